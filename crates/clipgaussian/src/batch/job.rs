//! Running a batch's jobs: one by index (what a job array's task runs), or all of them here,
//! several at once.
//!
//! A job whose output is finished is skipped; one that was interrupted (a checkpoint and no
//! finished mark) resumes from its checkpoint. SIGTERM and Ctrl-C stop a job after its current
//! step with a checkpoint. Each job's state is kept in `<batch>/state/<id>.json` (running,
//! done or failed, with the reason), its output in `<batch>/<id>/`.
//!
//! Exit codes of `batch run`: 0 done (or already done); [`EXIT_RETRY`] (75) worth running
//! again: interrupted or preempted (a checkpoint was saved), the device lost, the machine short
//! of memory, an output that could not be written; [`EXIT_NEVER_RETRY`] (65) never worth
//! running again as it is: a bad input, configuration or model file.

use std::error::Error;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use gs_stylize::checkpoint::finished_step;
use gs_stylize::error::causes;
use gs_stylize::evaluation::{resolve_clip, METRICS_JSON};
use gs_stylize::interrupt::{count_stops, stop_on_ctrl_c_once, SAME_STOP};
use gs_stylize::outputs::{read_json, write_json};
use gs_stylize::{RunOptions, StylizeError};
use serde::{Deserialize, Serialize};

use super::plan::{self, Job, Plan};

/// Exit code of a job worth running again (sysexits' `EX_TEMPFAIL`).
pub const EXIT_RETRY: u8 = 75;
/// Exit code of a job never worth running again as it is (sysexits' `EX_DATAERR`).
pub const EXIT_NEVER_RETRY: u8 = 65;

/// The folder of the jobs' state files in a batch folder.
pub const STATE_DIR: &str = "state";
/// The folder of the jobs' logs when `batch run --parallel` runs them.
pub const LOG_DIR: &str = "logs";

/// What a job's state file says.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobState {
    /// `running`, `done` or `failed`.
    pub status: String,
    /// The machine it ran on.
    pub host: String,
    /// The process that ran it.
    pub pid: u32,
    /// Wall time of the run so far (done or failed), seconds.
    pub seconds: Option<f64>,
    /// The exit code (done or failed).
    pub exit_code: Option<u8>,
    /// Why it failed.
    pub reason: Option<String>,
    /// Whether its stylization finished (written before it is scored, and kept when the
    /// scoring fails, so that running it again only scores it).
    #[serde(default)]
    pub stylized: bool,
}

/// The state file of `job` in the batch folder `dir`.
pub fn state_path(dir: &Path, job: &Job) -> PathBuf {
    dir.join(STATE_DIR).join(format!("{}.json", job.id))
}

/// The state of `job` in `dir`, when it has run.
pub fn read_state(dir: &Path, job: &Job) -> Option<JobState> {
    read_json(&state_path(dir, job)).ok()
}

/// Whether `job` of `plan` is finished in `dir`: its stylization wrote every output, and its
/// metrics are written when the plan asks for them.
pub fn is_done(dir: &Path, plan: &Plan, job: &Job) -> bool {
    is_done_with(dir, plan, job, read_state(dir, job).as_ref())
}

/// [`is_done`] of `job` whose state file says `state` (already read).
pub fn is_done_with(dir: &Path, plan: &Plan, job: &Job, state: Option<&JobState>) -> bool {
    is_stylized(dir, job, state)
        && (plan.eval.is_none() || job.out(dir).join(METRICS_JSON).is_file())
}

/// Whether the stylization of `job`, whose state file says `state`, wrote every output in
/// `dir` (its run finished, though its metrics may be left).
fn is_stylized(dir: &Path, job: &Job, state: Option<&JobState>) -> bool {
    let out = job.out(dir);
    out.is_dir()
        && (state.is_some_and(|s| s.status == "done" || s.stylized)
            || finished_step(&out).is_some_and(|step| step == job.steps()))
}

/// Writes the metrics of `job`, whose stylization is finished in `dir`, into its folder's
/// `metrics.json` when `plan` asks for them and they are not there yet.
fn score(dir: &Path, plan: &Plan, job: &Job) -> Result<(), Box<dyn Error>> {
    let Some(eval) = &plan.eval else {
        return Ok(());
    };
    let path = job.out(dir).join(METRICS_JSON);
    if path.is_file() {
        return Ok(());
    }
    println!("job {}: scoring with the CLIP metrics", job.index);
    let metrics = plan
        .modality
        .evaluate(&job.config_in(dir), eval.clip_files())
        .map_err(|e| e as Box<dyn Error>)?;
    write_json(&path, &metrics)?;
    Ok(())
}

/// This machine's name.
pub fn host() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .or_else(|_| std::env::var("HOSTNAME"))
        .unwrap_or_else(|_| "unknown".into())
}

/// The index a scheduler gives this task: Slurm's `SLURM_ARRAY_TASK_ID`, else Kubernetes'
/// `JOB_COMPLETION_INDEX`.
pub fn index_from_env() -> Option<usize> {
    ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"]
        .iter()
        .find_map(|name| std::env::var(name).ok()?.trim().parse().ok())
}

/// The exit code for a job that failed with `e`: [`EXIT_RETRY`] for an interruption, a lost
/// device, a machine short of memory or an output that could not be written, else
/// [`EXIT_NEVER_RETRY`].
pub fn exit_code_of(e: &(dyn Error + 'static)) -> u8 {
    for c in causes(e) {
        if let Some(e) = c.downcast_ref::<StylizeError>() {
            if matches!(
                e,
                StylizeError::Interrupted { .. }
                    | StylizeError::InterruptedFit { .. }
                    | StylizeError::Device(_)
                    | StylizeError::LossDevice(_)
                    | StylizeError::Render(_)
                    | StylizeError::Memory(_)
                    | StylizeError::Io { .. }
            ) {
                return EXIT_RETRY;
            }
        }
        if c.downcast_ref::<gs_core::fallible::OutOfMemory>().is_some() {
            return EXIT_RETRY;
        }
    }
    EXIT_NEVER_RETRY
}

/// Takes the lock of `job` in `dir` (`state/<id>.lock`, held while the returned file is open);
/// `None` when another process holds it.
fn lock_job(dir: &Path, job: &Job) -> Result<Option<std::fs::File>, String> {
    let states = dir.join(STATE_DIR);
    std::fs::create_dir_all(&states).map_err(|e| format!("{}: {e}", states.display()))?;
    let path = states.join(format!("{}.lock", job.id));
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    match file.try_lock() {
        Ok(()) => Ok(Some(file)),
        Err(std::fs::TryLockError::WouldBlock) => Ok(None),
        Err(std::fs::TryLockError::Error(e)) => Err(format!("{}: {e}", path.display())),
    }
}

/// Writes `state` as `job`'s state in `dir`.
fn write_state(dir: &Path, job: &Job, state: &JobState) -> Result<(), String> {
    let path = state_path(dir, job);
    std::fs::create_dir_all(dir.join(STATE_DIR)).map_err(|e| format!("{}: {e}", path.display()))?;
    write_json(&path, state).map_err(|e| e.to_string())
}

/// Runs job `index` of the batch in `dir` in this process (see the module documentation) and
/// returns the exit code.
pub fn run_one(dir: &Path, index: usize, progress: bool) -> u8 {
    let plan = match plan::read(dir) {
        Ok(plan) => plan,
        Err(e) => {
            eprintln!("error: {e}");
            // A plan that cannot be read now (a network file system's hiccup) may be readable
            // later; one that does not parse will not.
            return match std::fs::read_to_string(dir.join(plan::JOBS_JSON)) {
                Ok(_) => EXIT_NEVER_RETRY,
                Err(_) => EXIT_RETRY,
            };
        }
    };
    let Some(job) = plan.jobs.get(index) else {
        eprintln!(
            "error: --index {index}: the batch in {} has jobs 0 to {}",
            dir.display(),
            plan.jobs.len().saturating_sub(1)
        );
        return EXIT_NEVER_RETRY;
    };
    let what = format!(
        "job {index} ({}: {} x {})",
        job.id, job.input_label, job.style_label
    );
    if is_done(dir, &plan, job) {
        println!("{what} is done");
        return 0;
    }
    // One process a job: a second `batch run` of it (here, or a scheduler's task beside a
    // local run) leaves it to the first.
    let lock = match lock_job(dir, job) {
        Ok(Some(lock)) => lock,
        Ok(None) => {
            eprintln!("error: {what} is being run by another process; run it again later");
            return EXIT_RETRY;
        }
        Err(e) => {
            eprintln!("error: {e}");
            return EXIT_RETRY;
        }
    };
    let out = job.out(dir);
    // A save cut short between its two renames left the checkpoint parked: put it back first.
    if out.is_dir() {
        if let Err(e) = gs_stylize::checkpoint::recover_interrupted_save(&out) {
            eprintln!("error: {what}: {e}");
            return EXIT_RETRY;
        }
    }
    let resume = gs_stylize::checkpoint::checkpoint_dir(&out).is_dir();
    let earlier = read_state(dir, job);
    let stylized = is_stylized(dir, job, earlier.as_ref());
    // Metrics of an earlier stylization do not describe a new one.
    let metrics = out.join(METRICS_JSON);
    if !stylized && metrics.is_file() {
        if let Err(e) = std::fs::remove_file(&metrics) {
            eprintln!("error: {what}: {}: {e}", metrics.display());
            return EXIT_RETRY;
        }
    }

    println!(
        "{what}: {} {}",
        match (stylized, resume) {
            (true, _) => "stylized; scoring",
            (false, true) => "resuming into",
            (false, false) => "starting into",
        },
        out.display()
    );
    let mut state = JobState {
        status: "running".into(),
        host: host(),
        pid: std::process::id(),
        seconds: None,
        exit_code: None,
        reason: None,
        stylized,
    };
    if let Err(e) = write_state(dir, job, &state) {
        eprintln!("error: {e}");
        return EXIT_RETRY;
    }
    // The wall time of the whole job: an earlier run's stylization and this run's scoring.
    let before = if stylized {
        earlier.and_then(|s| s.seconds).unwrap_or(0.0)
    } else {
        0.0
    };
    let started = Instant::now();
    // A stop may reach a job twice (a scheduler signals every process, a batch passes its own
    // on): one within SAME_STOP of the first is the same; a later one quits at once, its state
    // recorded as stopped.
    let quit = {
        let (dir, job, state) = (dir.to_path_buf(), job.clone(), state.clone());
        move || {
            let mut state = state.clone();
            state.status = "failed".into();
            state.exit_code = Some(EXIT_RETRY);
            state.reason = Some(
                "quit at once by a second stop; running it again resumes from its last \
                 checkpoint"
                    .into(),
            );
            let _ = write_state(&dir, &job, &state);
        }
    };
    let result = stop_on_ctrl_c_once(SAME_STOP, EXIT_RETRY, quit)
        .map_err(|e| Box::new(e) as Box<dyn Error>)
        .and_then(|stop| {
            let options = RunOptions {
                resume,
                progress,
                stop,
            };
            // CLIP's files for the scores found before hours of stylizing, not after.
            if let Some(eval) = &plan.eval {
                resolve_clip(&eval.clip_files()).map_err(|e| {
                    format!(
                        "the manifest's eval: {e} (in a batch, give CLIP's files as \
                         eval.clip_config, eval.clip_weights and eval.tokenizer)"
                    )
                })?;
            }
            if stylized {
                return Ok(());
            }
            plan.modality.run(&job.config_in(dir), &options)?;
            state.stylized = true;
            state.seconds = Some(started.elapsed().as_secs_f64());
            write_state(dir, job, &state).map_err(|e| e.into())
        })
        .and_then(|()| score(dir, &plan, job));
    let code = match &result {
        Ok(()) => 0,
        Err(e) => exit_code_of(e.as_ref()),
    };
    state.status = if code == 0 { "done" } else { "failed" }.into();
    state.seconds = Some(before + started.elapsed().as_secs_f64());
    state.exit_code = Some(code);
    state.reason = result.as_ref().err().map(|e| e.to_string());
    if let Err(e) = write_state(dir, job, &state) {
        eprintln!("error: {e}");
    }
    drop(lock);
    match result {
        Ok(()) => println!("{what} is done"),
        Err(e) if code == EXIT_RETRY => eprintln!(
            "error: {what}: {e}\n(exit {EXIT_RETRY}: running the job again resumes it; `batch run` \
             passes --resume itself)"
        ),
        Err(e) => eprintln!("error: {what}: {e}"),
    }
    code
}

/// How `batch run` runs every job here.
#[derive(Clone, Debug)]
pub struct Parallel {
    /// Jobs at once.
    pub jobs: usize,
    /// Threads each job may use (`RAYON_NUM_THREADS`).
    pub threads: usize,
    /// GPUs to share out, one job per GPU at a time (`CUDA_VISIBLE_DEVICES`); none: leave the
    /// devices as they are.
    pub gpus: Option<usize>,
}

/// Runs every job of the batch in `dir` that is not done, `parallel.jobs` at once, each in a
/// process of this program (`batch run --index`) logging to `<batch>/logs/<index>.log`; returns
/// 0 when all are done, else [`EXIT_RETRY`] when any may be retried or is left, else
/// [`EXIT_NEVER_RETRY`]. Ctrl-C or SIGTERM starts no new job and passes SIGTERM on to the
/// running ones (which stop with a checkpoint), then waits for them; a second stop quits the
/// running ones at once (their states say stopped).
pub fn run_all(dir: &Path, parallel: &Parallel) -> Result<u8, String> {
    let plan = plan::read(dir)?;
    let pending: Vec<&Job> = plan
        .jobs
        .iter()
        .filter(|j| !is_done(dir, &plan, j))
        .collect();
    let devices = gpu_devices(parallel.gpus);
    // One job per GPU when GPUs are shared out; on the CPU as many as asked.
    let slots = match devices.len() {
        0 => parallel.jobs.max(1),
        gpus => gpus.min(parallel.jobs.max(1)),
    };
    println!(
        "{} of {} jobs to run, {slots} at once, {} threads each",
        pending.len(),
        plan.jobs.len(),
        parallel.threads
    );
    // This process never quits on a stop: it passes each on (the jobs, in their own process
    // groups, see a terminal's Ctrl-C only through it) and waits for the jobs.
    let stops = count_stops(SAME_STOP).map_err(|e| e.to_string())?;
    let logs = dir.join(LOG_DIR);
    std::fs::create_dir_all(&logs).map_err(|e| format!("{}: {e}", logs.display()))?;
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let mut free: Vec<usize> = (0..slots).rev().collect();
    let mut running: Vec<(Child, &Job, usize)> = Vec::new();
    let mut queue = pending.into_iter();
    let mut codes: Vec<u8> = Vec::new();
    let mut failure: Option<String> = None;
    // Stops passed on to the running jobs: the first stops each after its step with a
    // checkpoint, a second quits them at once.
    let mut passed = 0;
    loop {
        let received = stops.load(std::sync::atomic::Ordering::SeqCst).min(2);
        let stopped = received > 0;
        while passed < received {
            passed += 1;
            for (child, _, _) in &running {
                let _ = Command::new("kill")
                    .args(["-TERM", &child.id().to_string()])
                    .status();
            }
        }
        while !stopped && failure.is_none() && !free.is_empty() {
            let Some(job) = queue.next() else { break };
            let slot = free.pop().expect("a free slot");
            let device = devices.get(slot).map(|d| (slot, d));
            match spawn(&exe, dir, job, parallel, device, &logs) {
                Ok(child) => running.push((child, job, slot)),
                Err(e) => {
                    failure = Some(e);
                    free.push(slot);
                }
            }
        }
        if running.is_empty() {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
        let mut k = 0;
        while k < running.len() {
            match running[k].0.try_wait() {
                Ok(None) => k += 1,
                outcome => {
                    let (_, job, slot) = running.swap_remove(k);
                    let code = match outcome {
                        Ok(Some(status)) => status.code().map_or(EXIT_RETRY, |c| c as u8),
                        _ => EXIT_RETRY,
                    };
                    let said = match code {
                        0 => "done".to_string(),
                        EXIT_RETRY => format!(
                            "stopped (exit {EXIT_RETRY}: running the batch again resumes it)"
                        ),
                        _ => format!("failed (exit {code})"),
                    };
                    println!("job {} ({}) {said}", job.index, job.id);
                    codes.push(code);
                    free.push(slot);
                }
            }
        }
    }
    if let Some(e) = failure {
        return Err(e);
    }
    let left = queue.count();
    Ok(if codes.iter().all(|&c| c == 0) && left == 0 {
        0
    } else if left > 0 || codes.iter().any(|&c| c != 0 && c != EXIT_NEVER_RETRY) {
        EXIT_RETRY
    } else {
        EXIT_NEVER_RETRY
    })
}

/// The devices to share out among the jobs, one job each at a time: `gpus` of them, taken from
/// the `CUDA_VISIBLE_DEVICES` this process was given when it names at least that many, else
/// numbered from 0; none without `gpus`.
fn gpu_devices(gpus: Option<usize>) -> Vec<String> {
    let Some(n) = gpus else {
        return Vec::new();
    };
    let given: Vec<String> = std::env::var("CUDA_VISIBLE_DEVICES")
        .map(|v| {
            v.split(',')
                .map(|d| d.trim().to_string())
                .filter(|d| !d.is_empty())
                .collect()
        })
        .unwrap_or_default();
    if given.len() >= n {
        given.into_iter().take(n).collect()
    } else {
        (0..n).map(|d| d.to_string()).collect()
    }
}

/// Starts `batch run <dir> --index <job>` in a process of `exe`, with `parallel.threads`
/// threads and, when given, the GPU `device` (its slot, and its CUDA name), its output appended
/// to `<logs>/<index>.log`.
fn spawn(
    exe: &Path,
    dir: &Path,
    job: &Job,
    parallel: &Parallel,
    device: Option<(usize, &String)>,
    logs: &Path,
) -> Result<Child, String> {
    let log = logs.join(format!("{}.log", job.index));
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log)
        .map_err(|e| format!("{}: {e}", log.display()))?;
    let err = file
        .try_clone()
        .map_err(|e| format!("{}: {e}", log.display()))?;
    let mut command = Command::new(exe);
    command
        .args(["batch", "run"])
        .arg(dir)
        .args(["--index", &job.index.to_string()])
        .env("RAYON_NUM_THREADS", parallel.threads.to_string())
        .stdout(file)
        .stderr(err)
        .stdin(std::process::Stdio::null())
        // Its own process group: a terminal's Ctrl-C reaches the batch, which passes it on
        // once, not the job directly as well.
        .process_group(0);
    if let Some((slot, device)) = device {
        // candle's CUDA device by CUDA_VISIBLE_DEVICES, the rasterizer's adapter by its index
        // among the GPUs the drivers list; both in PCI bus order.
        command
            .env("CUDA_DEVICE_ORDER", "PCI_BUS_ID")
            .env("CUDA_VISIBLE_DEVICES", device)
            .env(gs_wgpu::ADAPTER_VARIABLE, slot.to_string());
    }
    let child = command
        .spawn()
        .map_err(|e| format!("{}: {e}", exe.display()))?;
    println!(
        "job {} ({}) started, log {}",
        job.index,
        job.id,
        log.display()
    );
    Ok(child)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An error that wraps `source`, as a modality's error wraps the shared ones.
    #[derive(Debug, thiserror::Error)]
    #[error("modality: {source}")]
    struct Wrapped {
        #[source]
        source: Box<dyn Error + Send + Sync>,
    }

    fn code(e: impl Error + Send + Sync + 'static) -> u8 {
        let wrapped = Wrapped {
            source: Box::new(e),
        };
        exit_code_of(&wrapped)
    }

    #[test]
    fn failures_worth_retrying_are_told_from_bad_inputs_anywhere_in_the_chain() {
        let interrupted = StylizeError::InterruptedFit {
            what: "the picture".into(),
        };
        assert_eq!(code(interrupted), EXIT_RETRY);
        assert_eq!(code(StylizeError::Memory("needs 90 GB".into())), EXIT_RETRY);
        let out_of_memory = gs_core::fallible::OutOfMemory {
            bytes: 1 << 40,
            what: "the Gaussians' arrays",
        };
        assert_eq!(code(out_of_memory), EXIT_RETRY);
        let splat_file = gs_core::splats::SplatFileError::OutOfMemory {
            path: "scene.spz".into(),
            source: out_of_memory,
        };
        assert_eq!(code(splat_file), EXIT_RETRY);
        let disk_full = StylizeError::Io {
            path: "out/model.ply".into(),
            source: std::io::Error::other("No space left on device"),
        };
        assert_eq!(code(disk_full), EXIT_RETRY);
        assert_eq!(
            code(StylizeError::Config("steps: -1".into())),
            EXIT_NEVER_RETRY
        );
        assert_eq!(
            code(StylizeError::Input("1x1 picture".into())),
            EXIT_NEVER_RETRY
        );
        assert_eq!(
            code(std::io::Error::other("anything else")),
            EXIT_NEVER_RETRY
        );
    }
}
