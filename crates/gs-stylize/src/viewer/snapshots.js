// Frames of a page that holds Gaussians at a few times (snapshots): frame k is the k-th
// snapshot, sliced out of groups that hold every snapshot one after another (`frames` holds
// their count).
function frameAt(g, frame) {
  const frames = g.frames[0], n = g.opacity_logits.length / frames;
  const slice = (a, width) => a.slice(width * n * frame, width * n * (frame + 1));
  return {
    means: slice(g.means, 3), quats: slice(g.quats, 4), log_scales: slice(g.log_scales, 3),
    opacity_logits: slice(g.opacity_logits, 1), sh: slice(g.sh, g.sh.length / (frames * n)),
  };
}
