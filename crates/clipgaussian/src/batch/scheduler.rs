//! The batch as a cluster scheduler's own job: a Slurm job array (`batch slurm`) or a
//! Kubernetes Indexed Job (`batch k8s`), one task per job index, each running
//! `clipgaussian batch run <batch> --index <its index>` (the index from the scheduler's
//! environment). The batch folder and every input must be on a file system the nodes share,
//! at the same paths.

use std::path::Path;

use serde_json::json;

use super::job::{EXIT_NEVER_RETRY, EXIT_RETRY, LOG_DIR};
use super::plan;

/// The Slurm script's file in the batch folder.
pub const SBATCH_FILE: &str = "batch.sbatch";
/// The Kubernetes Job's file in the batch folder.
pub const K8S_FILE: &str = "batch-job.yaml";

/// What the scheduler's job asks for.
#[derive(Clone, Debug)]
pub struct Resources {
    /// GPUs per task.
    pub gpus: u32,
    /// CPU cores per task.
    pub cpus: u32,
    /// Memory per task, GB.
    pub memory_gb: u32,
    /// Time limit per task, Slurm's `--time` (e.g. `24:00:00`).
    pub time: String,
    /// Tasks at once (Slurm's `%max`, Kubernetes' `parallelism`).
    pub parallel: usize,
}

/// Slurm's options beyond [`Resources`].
#[derive(Clone, Debug)]
pub struct SlurmOptions {
    /// The partition, if any.
    pub partition: Option<String>,
    /// The `clipgaussian` program the tasks run.
    pub program: String,
}

/// Kubernetes' options beyond [`Resources`].
#[derive(Clone, Debug)]
pub struct K8sOptions {
    /// The container image holding `clipgaussian`.
    pub image: String,
    /// The PersistentVolumeClaim holding the batch folder (mounted at the same path); none:
    /// the node's own folder of that path (`hostPath`).
    pub claim: Option<String>,
    /// The PersistentVolumeClaim holding the manifest's folder (its inputs, mounted at the
    /// same path); none: the node's own folder of that path.
    pub inputs_claim: Option<String>,
    /// Retries of one index on a failure worth retrying (`backoffLimitPerIndex`).
    pub retries: u32,
}

/// The `sbatch` script of the batch in `dir`: a job array over its jobs, `%parallel` at once;
/// each task logs to `<batch>/logs/<array id>_<index>.out` (a folder that must exist when the
/// array is submitted), gets SIGTERM two minutes before its time limit (Slurm's USR1 to the
/// script, passed on; a cancel or preemption's own SIGTERM reaches the job once), stopping
/// with a checkpoint, and is requeued when it exits with [`EXIT_RETRY`].
pub fn slurm_script(
    dir: &Path,
    resources: &Resources,
    options: &SlurmOptions,
) -> Result<String, String> {
    let plan = plan::read(dir)?;
    let n = plan.jobs.len();
    let dir = dir.display().to_string();
    if dir.chars().any(|c| c.is_control() || c == '"') || options.program.contains('\n') {
        return Err(format!(
            "{dir:?}: a batch folder for Slurm needs a path without quotes or control characters"
        ));
    }
    let quote = |s: &str| format!("'{}'", s.replace('\'', r"'\''"));
    // Slurm reads `%` in --output as a pattern: the folder's own are doubled.
    let log_pattern = format!("{}/{LOG_DIR}/%A_%a.out", dir.replace('%', "%%"));
    let mut lines = vec![
        "#!/bin/bash".to_string(),
        format!("#SBATCH --job-name=clipgaussian-{}", plan.modality.name()),
        format!(
            "#SBATCH --array=0-{}%{}",
            n.saturating_sub(1),
            resources.parallel.max(1)
        ),
        format!("#SBATCH --output=\"{log_pattern}\""),
        // A requeued task adds to its log.
        "#SBATCH --open-mode=append".to_string(),
        "#SBATCH --ntasks=1".to_string(),
        format!("#SBATCH --cpus-per-task={}", resources.cpus),
        format!("#SBATCH --mem={}G", resources.memory_gb),
        format!("#SBATCH --time={}", resources.time),
        "#SBATCH --requeue".to_string(),
        "#SBATCH --signal=B:USR1@120".to_string(),
    ];
    if resources.gpus > 0 {
        lines.push(format!("#SBATCH --gpus-per-task={}", resources.gpus));
    }
    if let Some(p) = &options.partition {
        lines.push(format!("#SBATCH --partition={p}"));
    }
    lines.push(String::new());
    lines.push(format!(
        "# {n} jobs of {}. Exit {EXIT_RETRY}: interrupted, preempted, device lost or out of \
         memory (requeued);\n# exit {EXIT_NEVER_RETRY}: a bad input (not retried).",
        plan.manifest
            .display()
            .to_string()
            .replace(|c: char| c.is_control(), " ")
    ));
    lines.push(format!(
        r#"export RAYON_NUM_THREADS="${{SLURM_CPUS_PER_TASK:-{cpus}}}"
# The job runs in the background so that the shell can pass it Slurm's warning before the time
# limit (USR1) as one SIGTERM: it stops after its step with a checkpoint. A cancel or a
# preemption sends SIGTERM to the job itself; the shell only waits on (a second SIGTERM would
# make the job quit without its checkpoint).
trap 'kill -TERM "$child" 2>/dev/null' USR1
trap ':' TERM
{program} batch run {dir} --index "$SLURM_ARRAY_TASK_ID" &
child=$!
wait "$child"
rc=$?
while [ "$rc" -gt 128 ] && kill -0 "$child" 2>/dev/null; do
  wait "$child"
  rc=$?
done
if [ "$rc" -eq {EXIT_RETRY} ]; then
  scontrol requeue "${{SLURM_ARRAY_JOB_ID}}_${{SLURM_ARRAY_TASK_ID}}"
fi
exit "$rc""#,
        cpus = resources.cpus,
        program = quote(&options.program),
        dir = quote(&dir),
    ));
    Ok(lines.join("\n") + "\n")
}

/// The Kubernetes Indexed Job of the batch in `dir` (YAML), the batch folder and the
/// manifest's folder mounted at their paths: one completion per job,
/// `parallelism` at once, each index retried up to `retries` times, an index that exits with
/// [`EXIT_NEVER_RETRY`] failed at once, a pod evicted or preempted not counted as a failure.
pub fn k8s_job(dir: &Path, resources: &Resources, options: &K8sOptions) -> Result<String, String> {
    let plan = plan::read(dir)?;
    let n = plan.jobs.len();
    let dir_text = dir.display().to_string();
    let inputs_text = plan
        .manifest
        .parent()
        .unwrap_or(Path::new("/"))
        .display()
        .to_string();
    // The inputs' folder beside the batch folder, unless one holds the other (two mounts of
    // one path, or a mount inside a read-only one, are refused).
    let nested = dir.starts_with(&inputs_text) || Path::new(&inputs_text).starts_with(dir);
    let volume = |name: &str, claim: &Option<String>, path: &str| match claim {
        Some(claim) => json!({"name": name, "persistentVolumeClaim": {"claimName": claim}}),
        None => json!({"name": name, "hostPath": {"path": path, "type": "Directory"}}),
    };
    let mut limits = json!({
        "cpu": resources.cpus.to_string(),
        "memory": format!("{}Gi", resources.memory_gb),
    });
    if resources.gpus > 0 {
        limits["nvidia.com/gpu"] = json!(resources.gpus);
    }
    let (mounts, volumes) = if nested {
        let outer = if dir.starts_with(&inputs_text) {
            &inputs_text
        } else {
            &dir_text
        };
        (
            json!([{"name": "batch", "mountPath": outer}]),
            json!([volume("batch", &options.claim, outer)]),
        )
    } else {
        (
            json!([
                {"name": "batch", "mountPath": dir_text},
                {"name": "inputs", "mountPath": inputs_text, "readOnly": true}
            ]),
            json!([
                volume("batch", &options.claim, &dir_text),
                volume("inputs", &options.inputs_claim, &inputs_text)
            ]),
        )
    };
    // One Job a batch: a second batch of the modality is a Job of another name.
    let name = format!(
        "clipgaussian-{}-{}",
        plan.modality.name(),
        plan::short_hash(dir_text.as_bytes(), 4)
    );
    let job = json!({
        "apiVersion": "batch/v1",
        "kind": "Job",
        "metadata": {"name": name},
        "spec": {
            "completionMode": "Indexed",
            "completions": n,
            "parallelism": resources.parallel.max(1),
            "backoffLimitPerIndex": options.retries,
            "maxFailedIndexes": n,
            "podFailurePolicy": {"rules": [
                {"action": "FailIndex",
                 "onExitCodes": {"containerName": "clipgaussian", "operator": "In",
                                 "values": [EXIT_NEVER_RETRY]}},
                {"action": "Ignore", "onPodConditions": [{"type": "DisruptionTarget"}]}
            ]},
            "template": {"spec": {
                "restartPolicy": "Never",
                "terminationGracePeriodSeconds": 120,
                "containers": [{
                    "name": "clipgaussian",
                    "image": options.image,
                    "command": ["clipgaussian", "batch", "run", dir_text],
                    "env": [{"name": "RAYON_NUM_THREADS", "value": resources.cpus.to_string()}],
                    "resources": {"limits": limits},
                    "volumeMounts": mounts
                }],
                "volumes": volumes
            }}
        }
    });
    let yaml = serde_yaml_ng::to_string(&job).map_err(|e| e.to_string())?;
    Ok(format!(
        "# {n} jobs of {}; each pod runs the job of its JOB_COMPLETION_INDEX.\n{yaml}",
        plan.manifest.display()
    ))
}
