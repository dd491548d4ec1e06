// A VeGaS frame in the viewer page: the JavaScript twin of base-vegas's `build_frame` (frame.rs)
// and `frame_time` (time.rs), from a model's parameter groups by name.
//
// Frame f sits at time t = the sum of the first f softmax weights of the time logits. A
// Gaussian with u = sigmoid(m) - t and delta = exp(-u^2 / (2 e^(2 sigma))) is drawn when
// delta > 0.01 and both in-plane scales delta e^s exceed 1e-4; its mean is
// (x + sum_i w[2i] u^(i+1), 0, z + sum_i w[2i+1] u^(i+1)), its log-scales
// (s_x, ln 1e-8, s_z) + ln delta, its rotation (cos a, 0, sin a, 0) with a = pi sigmoid(r),
// its opacity and colour as stored (SH degree 0). A Gaussian not drawn gets a zero quaternion
// (the page then draws nothing of it, as gs-core culls it).
function frameAt(g, frame) {
  const n = g.m.length, POLY = 7, sigmoid = (v) => 1 / (1 + Math.exp(-v));
  const logits = g.time;
  let max = -Infinity;
  for (const l of logits) max = Math.max(max, l);
  let sum = 0;
  const e = Array.from(logits, (l) => { const v = Math.exp(l - max); sum += v; return v; });
  let t = 0;
  for (let j = 0; j < frame; j++) t += e[j] / sum;
  const out = {
    means: new Float32Array(3 * n), quats: new Float32Array(4 * n),
    log_scales: new Float32Array(3 * n), opacity_logits: new Float32Array(n), sh: new Float32Array(3 * n),
  };
  const flat = Math.log(1e-8);
  for (let i = 0; i < n; i++) {
    const u = sigmoid(g.m[i]) - t, width = Math.exp(g.sigma[i]);
    const lnDelta = -(u * u) / (width * width) / 2, delta = Math.exp(lnDelta);
    const sx = g.scaling[2 * i], sz = g.scaling[2 * i + 1];
    out.opacity_logits[i] = g.opacity[i];
    out.sh.set(g.f_dc.subarray(3 * i, 3 * i + 3), 3 * i);
    if (!(delta > 0.01 && delta * Math.exp(sx) > 1e-4 && delta * Math.exp(sz) > 1e-4)) continue;
    let x = g.xyz[3 * i], z = g.xyz[3 * i + 2], power = u;
    for (let k = 0; k < POLY; k++) {
      x += g.w[2 * POLY * i + 2 * k] * power;
      z += g.w[2 * POLY * i + 2 * k + 1] * power;
      power *= u;
    }
    out.means.set([x, 0, z], 3 * i);
    out.log_scales.set([sx + lnDelta, flat + lnDelta, sz + lnDelta], 3 * i);
    const a = Math.PI * sigmoid(g.rotation[i]);
    out.quats.set([Math.cos(a), 0, Math.sin(a), 0], 4 * i);
  }
  return out;
}
