//! D-MiSo's starting model and its switch to sub-Gaussians.
//!
//! - [`initial_model`]: random points in the cube `[-1.3, 1.3]^3` (D-MiSo's start when the
//!   scene has no `points3d.ply`, as D-NeRF scenes have not), each a triangle
//!   `(p, p + d e_z, p + d e_y)` with `d` the root mean squared distance to its 3 nearest
//!   others; SH DC coefficients uniform in `[0, 1/255]` (nearly grey), opacity 0.1; the network with PyTorch's default initialisation. It
//!   has one sub-Gaussian per core that is the core itself (offsets and log-scales 0, identity
//!   rotation, the time-rotation layer `[I | 0]`), so it renders the cores as D-MiSo does
//!   before its sub-Gaussians exist.
//! - [`with_sub_gaussians`]: D-MiSo's `setup_attached_gauss`: `cores` cores drawn and `K`
//!   sub-Gaussians each, at the core (offsets and log-scales 0, identity rotation) with the
//!   core's colour and opacity.

use candle_core::Device;
use gs_core::plane_neighbours::{mean_nearest_dist2, MIN_DIST2};
use rand::seq::index::sample;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::deform_net::NetShape;
use crate::model::{group, group_lens, Dmiso, DmisoParams, SH_REST};
use crate::sub_gaussian::TIME_NET_INPUT;

/// Half the side of the cube the initial points are drawn in (D-MiSo's 1.3).
pub const INIT_HALF_SIDE: f64 = 1.3;

/// The opacity of the initial cores.
pub const INIT_OPACITY: f64 = 0.1;

/// The time-rotation layer that passes the quaternion through: weight `[I_4 | 0]`, bias 0.
pub fn identity_time_net() -> Vec<f32> {
    let mut layer = vec![0.0; 4 * TIME_NET_INPUT + 4];
    for r in 0..4 {
        layer[r * TIME_NET_INPUT + r] = 1.0;
    }
    layer
}

/// PyTorch's default `nn.Linear` initialisation of every layer of a network of `net`'s size:
/// weights and biases uniform in `+-1 / sqrt(fan_in)`.
pub fn default_network(net: &NetShape, rng: &mut impl Rng) -> Vec<f32> {
    let mut values = Vec::with_capacity(net.len());
    let tensors = net.tensors();
    for pair in tensors.chunks(2) {
        let fan_in = pair[0].1[1] as f64;
        let bound = 1.0 / fan_in.sqrt();
        for (_, shape) in pair {
            let n: usize = shape.iter().product();
            values.extend((0..n).map(|_| rng.random_range(-bound..bound) as f32));
        }
    }
    values
}

/// `points` random cores (one sub-Gaussian each, no deformation yet) and a network of `net`'s
/// size on `device`, from `seed`.
pub fn initial_model(
    points: usize,
    net: NetShape,
    seed: u64,
    device: &Device,
) -> Result<Dmiso, String> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let centres: Vec<[f64; 3]> = (0..points)
        .map(|_| [0; 3].map(|_| rng.random_range(-INIT_HALF_SIDE..INIT_HALF_SIDE)))
        .collect();
    let dist2 = mean_nearest_dist2(&centres, 3);
    let lens = group_lens(points, 1, &net);
    let mut groups: [Vec<f32>; 9] = lens.map(|n| vec![0.0; n]);
    for (c, (p, d2)) in centres.iter().zip(&dist2).enumerate() {
        let d = d2.max(MIN_DIST2).sqrt();
        let triangle = [*p, [p[0], p[1], p[2] + d], [p[0], p[1] + d, p[2]]];
        for (j, v) in triangle.iter().enumerate() {
            for a in 0..3 {
                groups[group::PSEUDOMESH][9 * c + 3 * j + a] = v[a] as f32;
            }
        }
        // D-MiSo's random points: SH DC coefficients uniform in [0, 1/255], nearly grey.
        for a in 0..3 {
            groups[group::DC][3 * c + a] = (rng.random::<f64>() / 255.0) as f32;
        }
        groups[group::ROTATION][4 * c] = 1.0;
    }
    let logit = (INIT_OPACITY / (1.0 - INIT_OPACITY)).ln() as f32;
    groups[group::OPACITY].fill(logit);
    groups[group::DEFORM] = default_network(&net, &mut rng);
    groups[group::TIME_NET] = identity_time_net();
    Dmiso::new(
        points,
        1,
        net,
        false,
        DmisoParams { groups },
        device.clone(),
    )
}

/// `model` (one sub-Gaussian per core: the core) turned into `cores` cores drawn from it
/// without repetition (all of them when it has no more), each with `subs` sub-Gaussians at the
/// core with its colour and opacity; the network and the time-rotation layer kept, the
/// deformation on.
pub fn with_sub_gaussians(
    model: &Dmiso,
    cores: usize,
    subs: usize,
    seed: u64,
) -> Result<Dmiso, String> {
    if model.subs_per_core() != 1 {
        return Err(format!(
            "the model already has {} sub-Gaussians per core",
            model.subs_per_core()
        ));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut drawn = sample(&mut rng, model.cores(), cores.min(model.cores())).into_vec();
    drawn.sort_unstable();
    let g = &model.params().groups;
    let net = model.net();
    let lens = group_lens(drawn.len(), subs, &net);
    let mut groups: [Vec<f32>; 9] = lens.map(Vec::with_capacity);
    for &c in &drawn {
        groups[group::PSEUDOMESH].extend_from_slice(&g[group::PSEUDOMESH][9 * c..9 * c + 9]);
        for _ in 0..subs {
            groups[group::ALPHA].extend_from_slice(&[0.0; 3]);
            groups[group::SCALE].extend_from_slice(&[0.0; 3]);
            groups[group::ROTATION].extend_from_slice(&[1.0, 0.0, 0.0, 0.0]);
            groups[group::OPACITY].push(g[group::OPACITY][c]);
            groups[group::DC].extend_from_slice(&g[group::DC][3 * c..3 * c + 3]);
            groups[group::REST].extend_from_slice(&g[group::REST][SH_REST * c..SH_REST * (c + 1)]);
        }
    }
    groups[group::DEFORM] = g[group::DEFORM].clone();
    groups[group::TIME_NET] = g[group::TIME_NET].clone();
    Dmiso::new(
        drawn.len(),
        subs,
        net,
        true,
        DmisoParams { groups },
        model.device().clone(),
    )
}
