//! `clipgaussian`: the command line of the workspace: `batch` (many stylizations from one
//! manifest, here or through a cluster's scheduler) and `fit-demo` (fit a random Gaussian set
//! to renders of the embedded default scene and write before/after pictures).

mod batch;
mod demo_scene;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use gs_core::adam::{AdamHyper, LrSchedule};
use gs_core::image_loss::{psnr, PhotometricObjective};
use gs_core::model::{GaussianLrs, View};
use gs_core::raster::render;
use gs_core::sampler::ViewSampler;
use gs_core::{GaussianSet, Image};
use gs_wgpu::backend::{DeviceChoice, OpenDevice, Trainer};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(Parser)]
#[command(version, about = "CLIPGaussian style transfer for Gaussian splatting")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Fit a random Gaussian set to renders of the embedded default scene (a striped torus
    /// around a ball) with L1 + D-SSIM, and write before/after pictures.
    FitDemo(FitDemoArgs),
    /// Many stylizations from one manifest (inputs x styles): plan them, run them here or as
    /// a Slurm job array or a Kubernetes Indexed Job, follow and collect them.
    #[command(subcommand)]
    Batch(BatchCommand),
}

#[derive(Subcommand)]
enum BatchCommand {
    /// Check a manifest and write the batch folder's jobs.json (one job per input and style,
    /// each with a stable id and its output folder `<batch>/<id>/`).
    Plan {
        /// The manifest (JSON: modality, config, set, inputs, styles, pairing).
        manifest: PathBuf,
        /// The batch folder.
        #[arg(long)]
        out: PathBuf,
    },
    /// Run one job by index (a scheduler's task), or every job not done here. A done job is
    /// skipped, an interrupted one resumes from its checkpoint. Exit 0: done; 75: worth
    /// running again (interrupted, preempted, device lost, out of memory); 65: never worth
    /// running again as it is (a bad input).
    Run {
        /// The batch folder.
        dir: PathBuf,
        /// The job to run; default: SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX when set, else
        /// every job not done.
        #[arg(long)]
        index: Option<usize>,
        /// Jobs at once when running every job (each in its own process).
        #[arg(long, default_value_t = 1)]
        parallel: usize,
        /// Threads each job may use when running every job; default: the machine's cores
        /// shared out.
        #[arg(long)]
        threads: Option<usize>,
        /// GPUs to share out when running every job, one job per GPU at a time
        /// (CUDA_VISIBLE_DEVICES).
        #[arg(long)]
        gpus: Option<usize>,
        /// Show no progress.
        #[arg(long)]
        quiet: bool,
    },
    /// Print each job's state (done, running, failed with the reason, stopped, left).
    Status {
        /// The batch folder.
        dir: PathBuf,
    },
    /// Write results.json, results.csv and contact_sheet.png into the batch folder.
    Collect {
        /// The batch folder.
        dir: PathBuf,
    },
    /// Write batch.sbatch: a Slurm job array over the jobs (submit with `sbatch`).
    Slurm {
        /// The batch folder.
        dir: PathBuf,
        #[command(flatten)]
        resources: ResourceArgs,
        /// The partition.
        #[arg(long)]
        partition: Option<String>,
    },
    /// Write batch-job.yaml: a Kubernetes Indexed Job over the jobs (`kubectl apply -f`).
    K8s {
        /// The batch folder.
        dir: PathBuf,
        #[command(flatten)]
        resources: ResourceArgs,
        /// The container image holding clipgaussian.
        #[arg(long)]
        image: String,
        /// The PersistentVolumeClaim holding the batch folder (mounted at the same path);
        /// default: the node's folder of that path (hostPath).
        #[arg(long)]
        claim: Option<String>,
        /// The PersistentVolumeClaim holding the manifest's folder and its inputs (mounted
        /// read-only at the same path); default: the node's folder of that path.
        #[arg(long)]
        inputs_claim: Option<String>,
        /// Retries of an index that fails in a way worth retrying.
        #[arg(long, default_value_t = 3)]
        retries: u32,
    },
}

/// What each task of a scheduler's job asks for.
#[derive(clap::Args)]
struct ResourceArgs {
    /// GPUs per task.
    #[arg(long, default_value_t = 1)]
    gpus: u32,
    /// CPU cores per task.
    #[arg(long, default_value_t = 8)]
    cpus: u32,
    /// Memory per task, GB.
    #[arg(long, default_value_t = 32)]
    memory_gb: u32,
    /// Time limit per task (Slurm's --time).
    #[arg(long, default_value = "24:00:00")]
    time: String,
    /// Tasks at once.
    #[arg(long, default_value_t = 4)]
    parallel: usize,
}

impl ResourceArgs {
    fn resources(&self) -> batch::scheduler::Resources {
        batch::scheduler::Resources {
            gpus: self.gpus,
            cpus: self.cpus,
            memory_gb: self.memory_gb,
            time: self.time.clone(),
            parallel: self.parallel,
        }
    }
}

#[derive(clap::Args)]
struct FitDemoArgs {
    /// Folder for the pictures (created if missing). Writes `views.png` (one row per view for
    /// the first four views: target | before | after) and `after.png` (the fitted set from
    /// view 0).
    #[arg(long, default_value = "out/fit-demo")]
    out: PathBuf,
    /// Optimisation steps, one view per step.
    #[arg(long, default_value_t = 1500)]
    steps: u64,
    /// Number of Gaussians fitted (fixed for the whole run).
    #[arg(long, default_value_t = 3000)]
    gaussians: usize,
    /// Number of training cameras on the ring around the scene.
    #[arg(long, default_value_t = 12)]
    views: usize,
    /// Render size in pixels (square).
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Seed of the initial Gaussians and of the view order.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Where to train: cpu, gpu, or auto (a real GPU when there is one, else the cpu).
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
}

fn main() -> std::process::ExitCode {
    match Cli::parse().command {
        Command::FitDemo(args) => match fit_demo(&args) {
            Ok(()) => std::process::ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
        Command::Batch(command) => std::process::ExitCode::from(batch_command(command)),
    }
}

/// Runs a `batch` subcommand; returns the exit code (see `batch run`'s). Batch folders are
/// taken as absolute paths: the jobs, logs and scheduler files name them wherever they run.
fn batch_command(mut command: BatchCommand) -> u8 {
    let dir = match &mut command {
        BatchCommand::Plan { out: dir, .. }
        | BatchCommand::Run { dir, .. }
        | BatchCommand::Status { dir }
        | BatchCommand::Collect { dir }
        | BatchCommand::Slurm { dir, .. }
        | BatchCommand::K8s { dir, .. } => dir,
    };
    match std::path::absolute(&*dir) {
        Ok(absolute) => *dir = absolute,
        Err(e) => {
            eprintln!("error: {}: {e}", dir.display());
            return batch::job::EXIT_NEVER_RETRY;
        }
    }
    use batch::job::EXIT_NEVER_RETRY;
    let written =
        |dir: &Path, name: &str, text: Result<String, String>| -> Result<String, String> {
            let path = dir.join(name);
            gs_core::fs::write_atomic(&path, text?.as_bytes())
                .map_err(|e| format!("{}: {e}", path.display()))?;
            Ok(format!("wrote {}", path.display()))
        };
    let line = match command {
        BatchCommand::Plan { manifest, out } => batch::plan::plan(&manifest, &out).map(|plan| {
            let done = plan
                .jobs
                .iter()
                .filter(|j| batch::job::is_done(&out, &plan, j))
                .count();
            format!(
                "planned {} jobs ({} inputs x {} styles, {done} already done) in {}",
                plan.jobs.len(),
                plan.inputs,
                plan.styles,
                out.join(batch::plan::JOBS_JSON).display()
            )
        }),
        BatchCommand::Run {
            dir,
            index,
            parallel,
            threads,
            gpus,
            quiet,
        } => {
            return match index.or_else(batch::job::index_from_env) {
                Some(index) => batch::job::run_one(&dir, index, !quiet),
                None => {
                    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
                    let parallel = batch::job::Parallel {
                        jobs: parallel.max(1),
                        threads: threads.unwrap_or((cores / parallel.max(1)).max(1)),
                        gpus,
                    };
                    batch::job::run_all(&dir, &parallel).unwrap_or_else(|e| {
                        eprintln!("error: {e}");
                        EXIT_NEVER_RETRY
                    })
                }
            };
        }
        BatchCommand::Status { dir } => {
            batch::status::statuses(&dir).map(|s| batch::status::report(&s).trim_end().to_string())
        }
        BatchCommand::Collect { dir } => batch::collect::collect(&dir),
        BatchCommand::Slurm {
            dir,
            resources,
            partition,
        } => {
            let program = std::env::current_exe()
                .map(|p| p.display().to_string())
                .unwrap_or_else(|_| "clipgaussian".into());
            let options = batch::scheduler::SlurmOptions { partition, program };
            let script = batch::scheduler::slurm_script(&dir, &resources.resources(), &options);
            // Slurm opens each task's log before the script runs: its folder must be there.
            let logs = dir.join(batch::job::LOG_DIR);
            let jobs = batch::plan::read(&dir).map_or(0, |p| p.jobs.len());
            std::fs::create_dir_all(&logs)
                .map_err(|e| format!("{}: {e}", logs.display()))
                .and_then(|()| written(&dir, batch::scheduler::SBATCH_FILE, script))
                .map(|line| {
                    if jobs > 1000 {
                        format!(
                            "{line}\nnote: {jobs} tasks; Slurm's default MaxArraySize takes \
                             indexes up to 1000 (ask the cluster's admins, or plan smaller \
                             batches)"
                        )
                    } else {
                        line
                    }
                })
        }
        BatchCommand::K8s {
            dir,
            resources,
            image,
            claim,
            inputs_claim,
            retries,
        } => {
            let options = batch::scheduler::K8sOptions {
                image,
                claim,
                inputs_claim,
                retries,
            };
            let job = batch::scheduler::k8s_job(&dir, &resources.resources(), &options);
            written(&dir, batch::scheduler::K8S_FILE, job)
        }
    };
    match line {
        Ok(line) => {
            println!("{line}");
            0
        }
        Err(e) => {
            eprintln!("error: {e}");
            EXIT_NEVER_RETRY
        }
    }
}

fn mean_psnr(model: &GaussianSet, views: &[View], targets: &[Image], bg: [f32; 3]) -> f64 {
    views
        .iter()
        .zip(targets)
        .map(|(v, t)| psnr(&render(model, &v.camera, bg).image, t))
        .sum::<f64>()
        / views.len() as f64
}

fn fit_demo(args: &FitDemoArgs) -> Result<()> {
    if args.views == 0 || args.gaussians == 0 || args.size < 16 {
        bail!("--views and --gaussians must be at least 1 and --size at least 16");
    }
    let backend = args.device.open()?;
    println!("device: {}", backend.describe());
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create the output folder {}", args.out.display()))?;
    let bg = [1.0f32; 3];
    let scene = demo_scene::default_scene();
    let views = demo_scene::ring_views(args.views, args.size)?;
    let targets: Vec<Image> = views
        .iter()
        .map(|v| render(&scene, &v.camera, bg).image)
        .collect();
    let initial = demo_scene::random_init(args.gaussians, args.seed);
    let before: Vec<Image> = views
        .iter()
        .map(|v| render(&initial, &v.camera, bg).image)
        .collect();
    let psnr_before = mean_psnr(&initial, &views, &targets, bg);

    // 3DGS's fitting rates, the means' rate scaled up for this small scene and decaying over
    // the run.
    let lrs = GaussianLrs {
        means: LrSchedule::Exponential {
            start: 1.6e-4 * 13.0,
            end: 1.6e-6 * 13.0,
            steps: args.steps,
        },
        scales: 0.005,
        rotations: 0.001,
        opacities: 0.05,
        feature: 0.0025,
    };
    let mut trainer = Trainer::new(&backend, initial, lrs.groups(), AdamHyper::default())?;
    let mut sampler = ViewSampler::new(views.len(), args.seed);
    let mut objective = PhotometricObjective::new(targets.clone(), 0.2);
    let bar = ProgressBar::new(args.steps).with_style(
        ProgressStyle::with_template(
            "{bar:40} {pos}/{len} steps, {elapsed} elapsed, ETA {eta}  {msg}",
        )
        .expect("valid template"),
    );
    let start = Instant::now();
    let mut phase_secs = [0.0f64; 3];
    for _ in 0..args.steps {
        let r = trainer.step(&views, sampler.next_batch(), bg, &mut objective)?;
        phase_secs[0] += r.render_time.as_secs_f64();
        phase_secs[1] += r.objective_time.as_secs_f64();
        phase_secs[2] += r.backward_time.as_secs_f64();
        bar.set_position(r.step);
        if r.step % 10 == 0 || r.step == args.steps {
            bar.set_message(format!("loss {:.4}", r.value.loss));
        }
    }
    bar.finish();
    let model = trainer.into_model();
    let psnr_after = mean_psnr(&model, &views, &targets, bg);

    let rows: Vec<Image> = views
        .iter()
        .zip(&targets)
        .zip(&before)
        .take(4)
        .map(|((v, t), b)| {
            let after = render(&model, &v.camera, bg).image;
            Image::side_by_side(&[t, b, &after])
        })
        .collect();
    save_rows(&rows, &args.out.join("views.png"))?;
    render(&model, &views[0].camera, bg)
        .image
        .save_png(&args.out.join("after.png"))?;
    println!(
        "fitted {} Gaussians in {:.1} s: mean PSNR over {} views {:.2} dB -> {:.2} dB",
        args.gaussians,
        start.elapsed().as_secs_f64(),
        views.len(),
        psnr_before,
        psnr_after
    );
    let per_step = |s: f64| 1e3 * s / args.steps.max(1) as f64;
    println!(
        "per step: render {:.1} ms, L1+SSIM {:.1} ms, backward + Adam {:.1} ms",
        per_step(phase_secs[0]),
        per_step(phase_secs[1]),
        per_step(phase_secs[2])
    );
    println!(
        "wrote {} and {}",
        args.out.join("views.png").display(),
        args.out.join("after.png").display()
    );
    Ok(())
}

/// Stacks equally wide images top to bottom and writes them as one PNG.
fn save_rows(rows: &[Image], path: &Path) -> Result<()> {
    let width = rows[0].width;
    let height = rows.iter().map(|r| r.height).sum();
    let data = rows.iter().flat_map(|r| r.data.iter().copied()).collect();
    Image {
        width,
        height,
        data,
    }
    .save_png(path)?;
    Ok(())
}
