//! D-MiSo's model of a dynamic scene behind [`BaseModel`]: core triangles, `K` sub-Gaussians per
//! core, the deformation network and the time-rotation layer. A view's time deforms every core
//! ([`crate::core_frame`]) and places its sub-Gaussians in the core's frame; only the
//! sub-Gaussians are rendered.
//!
//! Sub-Gaussian `i = core * K + k` at time `t`:
//! - mean `v1' + alpha_0 n + alpha_1 a / |a| + alpha_2 b / |b|`;
//! - log-scales `s + ln S` with the core's `S = [1e-8, |a| + eps, |b.r3|]`;
//! - rotation `normalize(L([q_sub, PE(t)])) * q_core` (Hamilton product, `L` the
//!   time-rotation layer `Linear(17, 4)`, `PE(t)` the 13-value time encoding);
//! - its own opacity logit and SH of degree 3.
//!
//! The network runs on its candle device; only the cores' 13 outputs and their gradients cross
//! between it and the host. Groups keep D-MiSo's names and layouts (`model_params.pt`'s, the
//! network's `state_dict` order).

use std::borrow::Cow;

use candle_core::Device;
use gs_core::gaussians::{GaussianGrads, GaussianSet};
use gs_core::model::{BaseModel, Forward, Group, ModelError, View};
use gs_core::raster::GradMask;
use gs_wgpu::GpuModel;
use rayon::prelude::*;

use crate::core_frame::{deform, deform_backward, frame, Deformation, FrameGrads, FrameState};
use crate::deform_net::{self, NetShape, NetTape, OUTPUTS};
use crate::encoding::{time_encoding, triangle_encoding, VERTEX_ENCODING};
use crate::sub_gaussian::{
    sub_gaussian, sub_gaussian_backward, SubGaussian, SubParams, TIME_NET_LEN,
};

/// The parameter groups, in order, with D-MiSo's names (`time_net` is its time-rotation layer,
/// saved under `time_net/`).
pub const GROUP_NAMES: [&str; 9] = [
    "pseudomesh",
    "alpha",
    "attached_scale",
    "attached_rotation",
    "attached_opacity",
    "attached_features_dc",
    "attached_features_rest",
    "deform",
    "time_net",
];

/// Group indices in [`GROUP_NAMES`].
pub mod group {
    /// Core triangles `[G, 3, 3]`.
    pub const PSEUDOMESH: usize = 0;
    /// Sub-Gaussian offsets in the core frame `[G, K, 3]`.
    pub const ALPHA: usize = 1;
    /// Sub-Gaussian log-scales relative to the core's `[G K, 3]`.
    pub const SCALE: usize = 2;
    /// Sub-Gaussian quaternions before the time-rotation layer `[G K, 4]`.
    pub const ROTATION: usize = 3;
    /// Sub-Gaussian opacity logits `[G K]`.
    pub const OPACITY: usize = 4;
    /// Degree-0 SH `[G K, 3]`.
    pub const DC: usize = 5;
    /// Degree 1-3 SH `[G K, 15, 3]`.
    pub const REST: usize = 6;
    /// The deformation network, flat in `state_dict` order.
    pub const DEFORM: usize = 7;
    /// The time-rotation layer: weight `[4, 17]` then bias `[4]`.
    pub const TIME_NET: usize = 8;
}

/// Adam's epsilon of the time-rotation layer: D-MiSo gives it an optimizer of its own with
/// `torch.optim.Adam`'s default (every other group: 1e-15).
pub const TORCH_ADAM_EPS: f64 = 1e-8;

/// SH degree of the sub-Gaussians.
pub const SH_DEGREE: usize = 3;

/// Higher-degree SH values per sub-Gaussian (`15 x 3`).
pub const SH_REST: usize = 45;

/// Cores handled by one parallel task.
const BLOCK: usize = 64;

/// The values of a D-MiSo model, in [`GROUP_NAMES`] order.
#[derive(Clone, Debug, PartialEq)]
pub struct DmisoParams {
    /// Every group's values.
    pub groups: [Vec<f32>; 9],
}

/// A D-MiSo model: `cores` triangles with `subs` sub-Gaussians each, a network of `net`'s
/// size on `device`, and whether the network deforms the cores (off during D-MiSo's warm-up).
#[derive(Clone, Debug)]
pub struct Dmiso {
    cores: usize,
    subs: usize,
    net: NetShape,
    /// Whether the network deforms the cores; off, every time renders the canonical cores.
    pub deformation: bool,
    params: DmisoParams,
    device: Device,
    /// The network's weights on `device`, kept between calls.
    resident: deform_net::ResidentWeights,
}

impl PartialEq for Dmiso {
    fn eq(&self, other: &Self) -> bool {
        (
            self.cores,
            self.subs,
            self.net,
            self.deformation,
            &self.params,
        ) == (
            other.cores,
            other.subs,
            other.net,
            other.deformation,
            &other.params,
        )
    }
}

impl Dmiso {
    /// A model of `cores` triangles with `subs` sub-Gaussians each from `params`, whose groups
    /// must have the lengths these sizes give (the error names the first that does not).
    pub fn new(
        cores: usize,
        subs: usize,
        net: NetShape,
        deformation: bool,
        params: DmisoParams,
        device: Device,
    ) -> Result<Self, String> {
        if cores == 0 || subs == 0 {
            return Err(format!(
                "a model needs cores and sub-Gaussians ({cores} cores of {subs})"
            ));
        }
        let want = group_lens(cores, subs, &net);
        for ((name, values), n) in GROUP_NAMES.iter().zip(&params.groups).zip(&want) {
            if values.len() != *n {
                return Err(format!(
                    "{name} holds {} values; {cores} cores of {subs} sub-Gaussians with a \
                     network of width {} need {n}",
                    values.len(),
                    net.width
                ));
            }
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                return Err(format!("{name}[{i}] is {}", values[i]));
            }
        }
        Ok(Self {
            cores,
            subs,
            net,
            deformation,
            params,
            device,
            resident: deform_net::ResidentWeights::default(),
        })
    }

    /// Number of core triangles.
    pub fn cores(&self) -> usize {
        self.cores
    }

    /// Sub-Gaussians per core.
    pub fn subs_per_core(&self) -> usize {
        self.subs
    }

    /// Number of rendered (sub-)Gaussians.
    pub fn len(&self) -> usize {
        self.cores * self.subs
    }

    /// Always false: a model has cores.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The network's size.
    pub fn net(&self) -> NetShape {
        self.net
    }

    /// The parameter values.
    pub fn params(&self) -> &DmisoParams {
        &self.params
    }

    /// The parameter values, to edit (their lengths must not change).
    pub fn params_mut(&mut self) -> &mut DmisoParams {
        &mut self.params
    }

    /// The candle device the network runs on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// The network's 13 outputs per core at time `t` (zeros without deformation).
    pub fn deformations(&self, t: f64) -> Result<Vec<f32>, ModelError> {
        Ok(self.run_net(t)?.0)
    }

    fn run_net(&self, t: f64) -> Result<(Vec<f32>, Option<NetTape>), ModelError> {
        if !self.deformation {
            return Ok((Vec::new(), None));
        }
        let mut encodings = Vec::with_capacity(self.cores * VERTEX_ENCODING);
        for v in self.params.groups[group::PSEUDOMESH].chunks_exact(9) {
            triangle_encoding(v, &mut encodings);
        }
        let (out, tape) = deform_net::forward(
            &self.net,
            &self.params.groups[group::DEFORM],
            &self.resident,
            &encodings,
            &time_encoding(t as f32),
            &self.device,
        )?;
        if let Some(i) = out.iter().position(|v| !v.is_finite()) {
            return Err(format!(
                "the deformation network gave {} for core {} at time {t}",
                out[i],
                i / OUTPUTS
            )
            .into());
        }
        Ok((out, Some(tape)))
    }
}

/// Group lengths of `cores` cores of `subs` sub-Gaussians with a network of `net`'s size.
pub fn group_lens(cores: usize, subs: usize, net: &NetShape) -> [usize; 9] {
    let n = cores * subs;
    [
        9 * cores,
        3 * n,
        3 * n,
        4 * n,
        n,
        3 * n,
        SH_REST * n,
        net.len(),
        TIME_NET_LEN,
    ]
}

/// The canonical triangle of core `c`.
fn vertices(pseudomesh: &[f32], c: usize) -> [[f64; 3]; 3] {
    let v = &pseudomesh[9 * c..9 * c + 9];
    [0, 1, 2].map(|j| [v[3 * j] as f64, v[3 * j + 1] as f64, v[3 * j + 2] as f64])
}

/// Sub-Gaussian `i`'s own parameters.
fn sub_params(g: &[Vec<f32>; 9], i: usize) -> SubParams {
    let f = |group: usize, n: usize| {
        let v = &g[group][n * i..n * (i + 1)];
        move |k: usize| v[k] as f64
    };
    let (alpha, scale, rotation) = (
        f(group::ALPHA, 3),
        f(group::SCALE, 3),
        f(group::ROTATION, 4),
    );
    SubParams {
        alpha: [0, 1, 2].map(alpha),
        scale: [0, 1, 2].map(scale),
        rotation: [0, 1, 2, 3].map(rotation),
    }
}

/// `slice` split into the parts of `block` cores of `per_core` values each (empty parts when
/// the slice is empty: a group without a gradient).
fn parts(slice: &mut [f32], per_core: usize, block: usize, count: usize) -> Vec<&mut [f32]> {
    if slice.is_empty() {
        (0..count).map(|_| Default::default()).collect()
    } else {
        slice.chunks_mut(per_core * block).collect()
    }
}

impl BaseModel for Dmiso {
    /// The network's tape and outputs (none without deformation).
    type Tape = Option<(NetTape, Vec<f32>)>;

    fn groups(&self) -> Vec<Group<'_>> {
        GROUP_NAMES
            .iter()
            .zip(&self.params.groups)
            .map(|(name, values)| Group::new(name, values))
            .collect()
    }

    fn groups_mut(&mut self) -> Vec<&mut [f32]> {
        self.params
            .groups
            .iter_mut()
            .map(|g| g.as_mut_slice())
            .collect()
    }

    fn grad_mask(&self, trained: &[bool]) -> GradMask {
        let geometry = [
            group::PSEUDOMESH,
            group::ALPHA,
            group::SCALE,
            group::ROTATION,
            group::DEFORM,
            group::TIME_NET,
        ]
        .iter()
        .any(|&g| trained[g]);
        GradMask {
            means: geometry,
            scales: geometry,
            rotations: geometry,
            opacities: trained[group::OPACITY],
            sh_dc: trained[group::DC],
            sh_rest: trained[group::REST],
        }
    }

    fn forward(&self, view: &View) -> Result<Forward<'_, Self::Tape>, ModelError> {
        if !(0.0..=1.0).contains(&view.time) {
            return Err(format!("view time {} is outside [0, 1]", view.time).into());
        }
        let (outputs, tape) = self.run_net(view.time)?;
        let te = time_encoding(view.time as f32);
        let (k, g) = (self.subs, &self.params.groups);
        let mut set = GaussianSet::zeros(self.len(), SH_DEGREE);
        set.opacity_logits.copy_from_slice(&g[group::OPACITY]);
        set.sh_dc.copy_from_slice(&g[group::DC]);
        set.sh_rest.copy_from_slice(&g[group::REST]);
        let blocks = self.cores.div_ceil(BLOCK);
        let means = parts(&mut set.means, 3 * k, BLOCK, blocks);
        let scales = parts(&mut set.log_scales, 3 * k, BLOCK, blocks);
        let quats = parts(&mut set.quats, 4 * k, BLOCK, blocks);
        means
            .into_par_iter()
            .zip(scales)
            .zip(quats)
            .enumerate()
            .for_each(|(block, ((means, scales), quats))| {
                for local in 0..means.len() / (3 * k) {
                    let c = block * BLOCK + local;
                    let d = (!outputs.is_empty())
                        .then(|| Deformation::from_slice(&outputs[OUTPUTS * c..OUTPUTS * (c + 1)]));
                    let p = deform(&vertices(&g[group::PSEUDOMESH], c), d.as_ref());
                    let f = frame(&p);
                    for s in 0..k {
                        let i = c * k + s;
                        let l = local * k + s;
                        let sub = sub_gaussian(&f, &sub_params(g, i), &g[group::TIME_NET], &te);
                        for a in 0..3 {
                            means[3 * l + a] = sub.mean[a] as f32;
                            scales[3 * l + a] = sub.log_scale[a] as f32;
                        }
                        for a in 0..4 {
                            quats[4 * l + a] = sub.quat[a] as f32;
                        }
                    }
                }
            });
        Ok(Forward {
            gaussians: Cow::Owned(set),
            tape: tape.map(|t| (t, outputs)),
        })
    }

    fn backward(
        &self,
        view: &View,
        tape: Self::Tape,
        grads: &GaussianGrads,
        trained: &[bool],
        out: &mut [Vec<f32>],
    ) -> Result<(), ModelError> {
        for (group, source) in [
            (group::OPACITY, &grads.opacity_logits),
            (group::DC, &grads.sh_dc),
            (group::REST, &grads.sh_rest),
        ] {
            if trained[group] {
                for (o, s) in out[group].iter_mut().zip(source) {
                    *o += s;
                }
            }
        }
        let mask = self.grad_mask(trained);
        if !mask.means {
            return Ok(());
        }
        let (net_tape, outputs) = match tape {
            Some((t, o)) => (Some(t), o),
            None => (None, Vec::new()),
        };
        let te = time_encoding(view.time as f32);
        let (k, g) = (self.subs, &self.params.groups);
        let blocks = self.cores.div_ceil(BLOCK);
        let mut deform_grads = vec![
            0.0f32;
            if net_tape.is_some() {
                OUTPUTS * self.cores
            } else {
                0
            }
        ];
        let [pseudomesh, alpha, scale, rotation, ..] = out else {
            unreachable!("nine groups")
        };
        let items = parts(pseudomesh, 9, BLOCK, blocks)
            .into_iter()
            .zip(parts(alpha, 3 * k, BLOCK, blocks))
            .zip(parts(scale, 3 * k, BLOCK, blocks))
            .zip(parts(rotation, 4 * k, BLOCK, blocks))
            .zip(parts(&mut deform_grads, OUTPUTS, BLOCK, blocks))
            .enumerate()
            .collect::<Vec<_>>();
        let time_net_grad = items
            .into_par_iter()
            .map(|(block, ((((g_mesh, g_alpha), g_scale), g_rot), g_def))| {
                let mut g_layer = [0.0f64; TIME_NET_LEN];
                let first = block * BLOCK;
                let last = (first + BLOCK).min(self.cores);
                for c in first..last {
                    let local = c - first;
                    let d = (!outputs.is_empty())
                        .then(|| Deformation::from_slice(&outputs[OUTPUTS * c..OUTPUTS * (c + 1)]));
                    let v = vertices(&g[group::PSEUDOMESH], c);
                    let p = deform(&v, d.as_ref());
                    let state = FrameState::new(&p);
                    let f = state.frame();
                    let mut gf = FrameGrads::default();
                    for s in 0..k {
                        let i = c * k + s;
                        let l = local * k + s;
                        let upstream = SubGaussian {
                            mean: [0, 1, 2].map(|a| grads.means[3 * i + a] as f64),
                            log_scale: [0, 1, 2].map(|a| grads.log_scales[3 * i + a] as f64),
                            quat: [0, 1, 2, 3].map(|a| grads.quats[4 * i + a] as f64),
                        };
                        let g_own = sub_gaussian_backward(
                            &f,
                            &sub_params(g, i),
                            &g[group::TIME_NET],
                            &te,
                            &upstream,
                            &mut gf,
                            &mut g_layer,
                        );
                        for (part, values) in [
                            (&mut *g_alpha, &g_own.alpha[..]),
                            (&mut *g_scale, &g_own.scale[..]),
                            (&mut *g_rot, &g_own.rotation[..]),
                        ] {
                            let n = values.len();
                            if !part.is_empty() {
                                for (o, v) in part[n * l..n * (l + 1)].iter_mut().zip(values) {
                                    *o += *v as f32;
                                }
                            }
                        }
                    }
                    let g_p = state.backward(&gf);
                    let core = deform_backward(&v, d.as_ref(), &g_p);
                    if !g_mesh.is_empty() {
                        for j in 0..3 {
                            for a in 0..3 {
                                g_mesh[9 * local + 3 * j + a] += core.vertices[j][a] as f32;
                            }
                        }
                    }
                    if !g_def.is_empty() {
                        for (o, v) in g_def[OUTPUTS * local..OUTPUTS * (local + 1)]
                            .iter_mut()
                            .zip(core.deformation.to_array())
                        {
                            *o = v as f32;
                        }
                    }
                }
                g_layer
            })
            .collect::<Vec<_>>()
            // Summed in block order: the same result on every run.
            .into_iter()
            .fold([0.0f64; TIME_NET_LEN], |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    *x += y;
                }
                a
            });
        if trained[group::TIME_NET] {
            for (o, v) in out[group::TIME_NET].iter_mut().zip(time_net_grad) {
                *o += v as f32;
            }
        }
        if let (Some(net_tape), true) = (net_tape, trained[group::DEFORM]) {
            let g_net = deform_net::backward(net_tape, &deform_grads)?;
            for (o, v) in out[group::DEFORM].iter_mut().zip(g_net) {
                *o += v;
            }
        }
        Ok(())
    }
}

/// On a GPU the sub-Gaussians are built on the host (the network runs on candle's device) and
/// uploaded: the provided twins.
impl GpuModel for Dmiso {}

/// `(1 - t) a + t b` of every parameter of two models of the same cores, sub-Gaussians and
/// network (e.g. two stylizations of one fit: the Gaussians and the network's weights), or an
/// error naming what differs. `t` outside `[0, 1]` extrapolates.
pub fn interpolate(a: &Dmiso, b: &Dmiso, t: f32) -> Result<Dmiso, String> {
    let shape = |m: &Dmiso| (m.cores, m.subs, m.net.width);
    if shape(a) != shape(b) {
        return Err(format!(
            "{} cores of {} sub-Gaussians with a network of width {} against {} of {} with {}",
            a.cores, a.subs, a.net.width, b.cores, b.subs, b.net.width
        ));
    }
    if a.deformation != b.deformation {
        return Err("one model deforms its cores and the other does not".into());
    }
    gs_core::interpolate::blend_groups(a, b, t)
}
