//! Where a batch stands: each job done, running, failed (with its reason: a failure not worth
//! retrying), stopped (before it finished, in a way worth running again: interrupted, killed,
//! preempted) or left. A job running on another machine cannot be looked at from here: its
//! state says running until its process writes another.

use std::path::Path;

use super::job::{host, is_done_with, read_state};
use super::plan::{self, Job, Plan};

/// Where one job stands.
#[derive(Clone, Debug, PartialEq)]
pub enum JobStatus {
    /// Its outputs are written.
    Done,
    /// A process runs it (on `host`).
    Running {
        /// The machine.
        host: String,
    },
    /// It failed: exit code and reason.
    Failed {
        /// The exit code (`batch run`'s).
        exit_code: u8,
        /// The error.
        reason: String,
    },
    /// It stopped before it finished in a way worth running again (interrupted, preempted,
    /// killed, short of memory: exit 75, or its process gone); it resumes from its checkpoint
    /// when there is one.
    Stopped,
    /// It has not run.
    Left,
}

impl JobStatus {
    /// One word: `done`, `running`, `failed`, `stopped` or `left`.
    pub fn word(&self) -> &'static str {
        match self {
            Self::Done => "done",
            Self::Running { .. } => "running",
            Self::Failed { .. } => "failed",
            Self::Stopped => "stopped",
            Self::Left => "left",
        }
    }
}

/// Where `job` of `plan`, the batch in `dir`, stands (a stylized job whose metrics are left
/// is left).
pub fn job_status(dir: &Path, plan: &Plan, job: &Job) -> JobStatus {
    let state = read_state(dir, job);
    if is_done_with(dir, plan, job, state.as_ref()) {
        return JobStatus::Done;
    }
    match state {
        None => JobStatus::Left,
        // Interrupted, preempted, short of memory: worth running again, from its checkpoint.
        Some(s) if s.status == "failed" && s.exit_code == Some(super::job::EXIT_RETRY) => {
            JobStatus::Stopped
        }
        Some(s) if s.status == "failed" => JobStatus::Failed {
            exit_code: s.exit_code.unwrap_or(1),
            reason: s.reason.unwrap_or_default(),
        },
        Some(s) if s.status == "running" => {
            // A process on another machine cannot be looked at from here: taken as running.
            let alive = s.host != host() || Path::new(&format!("/proc/{}", s.pid)).exists();
            if alive {
                JobStatus::Running { host: s.host }
            } else {
                JobStatus::Stopped
            }
        }
        Some(_) => JobStatus::Left,
    }
}

/// The status of every job of the batch in `dir`, by index.
pub fn statuses(dir: &Path) -> Result<Vec<(Job, JobStatus)>, String> {
    let plan = plan::read(dir)?;
    Ok(plan
        .jobs
        .iter()
        .map(|job| (job.clone(), job_status(dir, &plan, job)))
        .collect())
}

/// The lines `batch status` prints: one per job, then the counts.
pub fn report(statuses: &[(Job, JobStatus)]) -> String {
    let mut text = String::new();
    for (job, status) in statuses {
        let detail = match status {
            JobStatus::Running { host } => format!(" on {host}"),
            JobStatus::Failed { exit_code, reason } => format!(" (exit {exit_code}): {reason}"),
            _ => String::new(),
        };
        text += &format!(
            "{:>4}  {}  {:<8} {} x {}{detail}\n",
            job.index,
            job.id,
            status.word(),
            job.input_label,
            job.style_label
        );
    }
    let count = |word: &str| statuses.iter().filter(|(_, s)| s.word() == word).count();
    text += &format!(
        "{} jobs: {} done, {} running, {} failed, {} stopped, {} left\n",
        statuses.len(),
        count("done"),
        count("running"),
        count("failed"),
        count("stopped"),
        count("left")
    );
    text
}
