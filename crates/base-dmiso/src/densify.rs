//! D-MiSo's densification of the cores before their sub-Gaussians exist (3DGS's, on triangles):
//! each core's screen-space positional gradient is averaged over the views that saw it
//! ([`Recording`]); every `every` steps cores with a large gradient are cloned (small ones) or
//! split in two (large ones), and nearly transparent ones are pruned ([`densify`]); every
//! `opacity_reset_every` steps opacities are lowered to 0.01 ([`reset_opacity`]). The
//! optimizer's moments follow the rows ([`RowChange`]): kept for surviving cores, zero for new
//! ones, as PyTorch's optimizer state after 3DGS's densification.
//!
//! The screen-space gradient is 3DGS's "viewspace point" gradient (with respect to the
//! projected centre in normalized device coordinates, `W / 2` pixels per unit), recovered from
//! the gradient of the core's centre in the world: its component across the line of sight,
//! scaled by `depth / focal` and `W / 2` (`H / 2` vertically). That leaves out the centre's
//! small effect through the projected covariance and the view direction of the colour. A core
//! counts as seen when its centre is more than 0.2 in front of the camera and projects into the
//! picture. Unlike D-MiSo, which takes the last view of each batch, every view of a batch
//! counts.

use std::sync::Mutex;

use gs_core::adam::RowChange;
use gs_core::densify::standard_normal;
use gs_core::gaussians::GaussianGrads;
use gs_core::model::{BaseModel, Forward, Group, ModelError, View};
use gs_core::raster::GradMask;
use gs_wgpu::GpuModel;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::core_frame::frame;
use crate::model::{group, Dmiso, DmisoParams, SH_REST};

/// D-MiSo's densification settings (3DGS's defaults).
#[derive(Clone, Debug, PartialEq)]
pub struct DensifySettings {
    /// The first step after which cores are densified.
    pub from: u64,
    /// Steps between densifications.
    pub every: u64,
    /// Mean screen-space gradient from which a core is cloned or split.
    pub grad_threshold: f64,
    /// Cores whose largest canonical scale is above this fraction of the scene extent are
    /// split, the others cloned.
    pub percent_dense: f64,
    /// Cores below this opacity are pruned.
    pub min_opacity: f64,
    /// Steps between opacity resets.
    pub opacity_reset_every: u64,
}

impl Default for DensifySettings {
    fn default() -> Self {
        Self {
            from: 500,
            every: 100,
            grad_threshold: 2e-4,
            percent_dense: 0.01,
            min_opacity: 0.005,
            opacity_reset_every: 3000,
        }
    }
}

/// The screen-space gradient norms of every core, summed over the views that saw it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GradStats {
    /// Sum of the norms.
    pub sum: Vec<f64>,
    /// Views that saw the core.
    pub count: Vec<u32>,
}

impl GradStats {
    /// The mean norm of core `c` (0 when no view saw it).
    pub fn mean(&self, c: usize) -> f64 {
        if self.count[c] == 0 {
            0.0
        } else {
            self.sum[c] / self.count[c] as f64
        }
    }
}

/// A model of one sub-Gaussian per core (the cores themselves) that records its cores'
/// screen-space gradients in its backward.
#[derive(Debug)]
pub struct Recording {
    /// The model.
    pub model: Dmiso,
    stats: Mutex<GradStats>,
}

impl Clone for Recording {
    fn clone(&self) -> Self {
        Self {
            model: self.model.clone(),
            stats: Mutex::new(self.stats()),
        }
    }
}

impl Recording {
    /// `model` with empty statistics.
    pub fn new(model: Dmiso) -> Self {
        let n = model.cores();
        Self {
            model,
            stats: Mutex::new(GradStats {
                sum: vec![0.0; n],
                count: vec![0; n],
            }),
        }
    }

    /// `model` with the statistics gathered so far on its cores (which must be the same).
    pub fn with_stats(model: Dmiso, stats: GradStats) -> Self {
        debug_assert_eq!(stats.sum.len(), model.cores());
        Self {
            model,
            stats: Mutex::new(stats),
        }
    }

    /// The statistics so far.
    pub fn stats(&self) -> GradStats {
        self.stats.lock().expect("not poisoned").clone()
    }
}

impl BaseModel for Recording {
    /// The model's tape and the rendered centres.
    type Tape = (<Dmiso as BaseModel>::Tape, Vec<f32>);

    fn groups(&self) -> Vec<Group<'_>> {
        self.model.groups()
    }

    fn groups_mut(&mut self) -> Vec<&mut [f32]> {
        self.model.groups_mut()
    }

    fn grad_mask(&self, trained: &[bool]) -> GradMask {
        let mut mask = self.model.grad_mask(trained);
        mask.means = true;
        mask
    }

    fn forward(&self, view: &View) -> Result<Forward<'_, Self::Tape>, ModelError> {
        let Forward { gaussians, tape } = self.model.forward(view)?;
        let means = gaussians.means.clone();
        Ok(Forward {
            gaussians,
            tape: (tape, means),
        })
    }

    fn backward(
        &self,
        view: &View,
        (tape, means): Self::Tape,
        grads: &GaussianGrads,
        trained: &[bool],
        out: &mut [Vec<f32>],
    ) -> Result<(), ModelError> {
        self.model.backward(view, tape, grads, trained, out)?;
        let cam = &view.camera;
        let mut stats = self.stats.lock().expect("not poisoned");
        let k = self.model.subs_per_core();
        for (i, (m, g)) in means
            .chunks_exact(3)
            .zip(grads.means.chunks_exact(3))
            .enumerate()
        {
            let world = [m[0] as f64, m[1] as f64, m[2] as f64];
            let p = cam.to_camera(world);
            let Some(([u, v], _)) = cam.project(world) else {
                continue;
            };
            if p[2] <= 0.2
                || !(0.0..cam.width as f64).contains(&u)
                || !(0.0..cam.height as f64).contains(&v)
            {
                continue;
            }
            let gw = [g[0] as f64, g[1] as f64, g[2] as f64];
            let gc = gs_core::mat::mul_vec(&cam.rotation, &gw);
            let gx = gc[0] * p[2] / cam.fx * 0.5 * cam.width as f64;
            let gy = gc[1] * p[2] / cam.fy * 0.5 * cam.height as f64;
            let c = i / k;
            stats.sum[c] += (gx * gx + gy * gy).sqrt();
            stats.count[c] += 1;
        }
        Ok(())
    }
}

/// The provided GPU twins: the recording happens in the host forward and backward.
impl GpuModel for Recording {}

fn sigmoid(x: f32) -> f64 {
    1.0 / (1.0 + (-(x as f64)).exp())
}

/// Per-core widths of the groups (`None`: not per core).
fn row_widths() -> [Option<usize>; 9] {
    [
        Some(9),
        Some(3),
        Some(3),
        Some(4),
        Some(1),
        Some(3),
        Some(SH_REST),
        None,
        None,
    ]
}

/// `model` (one sub-Gaussian per core) densified after `stats` (see the module
/// documentation), in a scene of extent `extent`, and how each group's rows changed. Split
/// positions are drawn from `seed`.
pub fn densify(
    model: &Dmiso,
    stats: &GradStats,
    extent: f64,
    settings: &DensifySettings,
    seed: u64,
) -> Result<(Dmiso, Vec<RowChange>), String> {
    if model.subs_per_core() != 1 {
        return Err("only cores without sub-Gaussians are densified".into());
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let g = &model.params().groups;
    let widths = row_widths();
    let cores = model.cores();
    let mut groups: [Vec<f32>; 9] = std::array::from_fn(|i| match widths[i] {
        Some(_) => Vec::new(),
        None => g[i].clone(),
    });
    let mut from: Vec<Option<usize>> = Vec::new();
    let mut push_row =
        |groups: &mut [Vec<f32>; 9], c: usize, mesh: Option<[f32; 9]>, source: Option<usize>| {
            for (i, w) in widths.iter().enumerate() {
                if let Some(w) = w {
                    if i == group::PSEUDOMESH {
                        if let Some(m) = mesh {
                            groups[i].extend_from_slice(&m);
                            continue;
                        }
                    }
                    groups[i].extend_from_slice(&g[i][w * c..w * (c + 1)]);
                }
            }
            from.push(source);
        };
    let mut clones = Vec::new();
    let mut splits = Vec::new();
    for c in 0..cores {
        if sigmoid(g[group::OPACITY][c]) < settings.min_opacity {
            continue;
        }
        let large = stats.mean(c) >= settings.grad_threshold;
        let v = &g[group::PSEUDOMESH][9 * c..9 * c + 9];
        let tri = [0, 1, 2].map(|j| [0, 1, 2].map(|a| v[3 * j + a] as f64));
        let f = frame(&tri);
        let (s2, s3) = (f.log_scales[0].exp(), f.log_scales[1].exp());
        let big = s2.max(s3) > settings.percent_dense * extent;
        match (large, big) {
            (true, true) => splits.push((c, tri, f, s2, s3)),
            (true, false) => {
                push_row(&mut groups, c, None, Some(c));
                clones.push(c);
            }
            (false, _) => push_row(&mut groups, c, None, Some(c)),
        }
    }
    for c in clones {
        push_row(&mut groups, c, None, None);
    }
    for (c, tri, f, s2, s3) in splits {
        // The frame's axes (the columns of its rotation): the normal, then the two in-plane
        // axes.
        let r = gs_core::mat::quat_to_rotation(f.quat);
        let axis = |j: usize| [r[0][j], r[1][j], r[2][j]];
        let (r1, r2, r3) = (axis(0), axis(1), axis(2));
        for _ in 0..2 {
            let z = [
                1e-8 * standard_normal(&mut rng),
                s2 * standard_normal(&mut rng),
                s3 * standard_normal(&mut rng),
            ];
            let centre = [0, 1, 2].map(|a| tri[0][a] + z[0] * r1[a] + z[1] * r2[a] + z[2] * r3[a]);
            // D-MiSo's `create_faces`: legs of the scales / 1.6 along the in-plane axes, the
            // longer one first (to v2).
            let (mut l2, mut l3, mut d2, mut d3) = (s2 / 1.6, s3 / 1.6, r2, r3);
            if l2 <= l3 {
                (l2, l3, d2, d3) = (l3, l2, d3, d2);
            }
            let mut mesh = [0.0f32; 9];
            for a in 0..3 {
                mesh[a] = centre[a] as f32;
                mesh[3 + a] = (centre[a] + l2 * d2[a]) as f32;
                mesh[6 + a] = (centre[a] + l3 * d3[a]) as f32;
            }
            push_row(&mut groups, c, Some(mesh), None);
        }
    }
    let n = from.len();
    if n == 0 {
        return Err("densification pruned every core (all below the minimum opacity)".into());
    }
    debug_assert_eq!(groups[group::OPACITY].len(), n);
    let changes = widths
        .iter()
        .map(|w| match w {
            Some(width) => RowChange::Rows {
                width: *width,
                from: from.clone(),
            },
            None => RowChange::Keep,
        })
        .collect();
    let dense = Dmiso::new(
        n,
        1,
        model.net(),
        model.deformation,
        DmisoParams { groups },
        model.device().clone(),
    )?;
    Ok((dense, changes))
}

/// 3DGS's opacity reset: every opacity above 0.01 lowered to 0.01, and how each group's rows
/// changed (the opacity's moments restart).
pub fn reset_opacity(model: &mut Dmiso) -> Vec<RowChange> {
    let cap = (0.01f64 / 0.99).ln() as f32;
    for o in &mut model.params_mut().groups[group::OPACITY] {
        *o = o.min(cap);
    }
    (0..9)
        .map(|i| {
            if i == group::OPACITY {
                RowChange::Reset
            } else {
                RowChange::Keep
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use candle_core::Device;

    use super::*;
    use crate::deform_net::NetShape;
    use crate::init::initial_model;

    /// Four cores: 0 transparent, 1 small with a large gradient, 2 large with a large gradient,
    /// 3 with a small gradient.
    fn cores() -> (Dmiso, GradStats) {
        let mut model = initial_model(4, NetShape { width: 4 }, 0, &Device::Cpu).unwrap();
        let g = &mut model.params_mut().groups;
        let size = [0.01f32, 0.01, 0.5, 0.01];
        for c in 0..4 {
            let p = [c as f32, 0.0, 0.0];
            let s = size[c];
            let tri = [p, [p[0] + s, p[1], p[2]], [p[0], p[1] + s, p[2]]];
            g[group::PSEUDOMESH][9 * c..9 * c + 9].copy_from_slice(tri.as_flattened());
            g[group::DC][3 * c] = c as f32;
        }
        g[group::OPACITY][0] = -8.0;
        let stats = GradStats {
            sum: vec![1.0, 3e-4, 9e-4, 1e-4],
            count: vec![1, 1, 3, 1],
        };
        (model, stats)
    }

    #[test]
    fn large_gradients_clone_small_cores_and_split_large_ones() {
        let (model, stats) = cores();
        let settings = DensifySettings::default();
        let (dense, changes) = densify(&model, &stats, 2.0, &settings, 1).unwrap();
        // Core 0 pruned; 1 kept and cloned; 2 split in two; 3 kept.
        assert_eq!(dense.cores(), 5);
        let dc: Vec<f32> = dense.params().groups[group::DC]
            .chunks_exact(3)
            .map(|c| c[0])
            .collect();
        assert_eq!(dc, [1.0, 3.0, 1.0, 2.0, 2.0]);
        let RowChange::Rows { width, from } = &changes[group::PSEUDOMESH] else {
            panic!("the triangles change by rows");
        };
        assert_eq!(
            (*width, from.as_slice()),
            (9, &[Some(1), Some(3), None, None, None][..])
        );
        assert_eq!(changes[group::DEFORM], RowChange::Keep);
        let mesh = &dense.params().groups[group::PSEUDOMESH];
        assert_eq!(
            mesh[9..18],
            model.params().groups[group::PSEUDOMESH][27..36]
        );
        // The split halves lie in the original's plane (z = 0) with legs 0.5 / 1.6.
        for child in 3..5 {
            let t = &mesh[9 * child..9 * child + 9];
            assert!(t.iter().skip(2).step_by(3).all(|z| z.abs() < 1e-6), "{t:?}");
            let leg = ((t[3] - t[0]).powi(2) + (t[4] - t[1]).powi(2)).sqrt();
            assert!((leg - 0.5 / 1.6).abs() < 1e-5, "{leg}");
        }
    }

    #[test]
    fn the_opacity_reset_caps_opacities_at_one_percent() {
        let (mut model, _) = cores();
        model.params_mut().groups[group::OPACITY][1] = 3.0;
        let changes = reset_opacity(&mut model);
        let o = &model.params().groups[group::OPACITY];
        assert!((sigmoid(o[1]) - 0.01).abs() < 1e-6);
        assert_eq!(o[0], -8.0);
        assert_eq!(changes[group::OPACITY], RowChange::Reset);
    }
}
