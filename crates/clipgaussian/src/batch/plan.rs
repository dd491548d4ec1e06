//! A planned batch: `<batch>/jobs.json`, one entry per job with a stable id and its resolved
//! configuration; job `id` writes `<batch>/<id>/`.
//!
//! The id is a hash of the modality, the job's whole configuration and, for every file or
//! folder it names, its path, size and modification time: the same job planned again keeps
//! its id (and so its finished or interrupted output), a job whose input or settings changed
//! gets a new one.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use gs_stylize::outputs::write_json;
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use sha2::{Digest, Sha256};

use super::manifest::{self, label, EvalRequest};
use super::modality::{ModalityKind, PATH_FIELDS};

/// The plan's file in the batch folder.
pub const JOBS_JSON: &str = "jobs.json";

/// A planned batch.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Plan {
    /// The manifest it was planned from.
    pub manifest: PathBuf,
    /// The modality of every job.
    pub modality: ModalityKind,
    /// Number of inputs of the manifest.
    pub inputs: usize,
    /// Number of styles of the manifest.
    pub styles: usize,
    /// The jobs, by index.
    pub jobs: Vec<Job>,
    /// The evaluation every job makes once stylized, when the manifest asks for one (its files
    /// absolute).
    #[serde(default)]
    pub eval: Option<EvalRequest>,
}

/// One planned job.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Job {
    /// Its index (`batch run --index`, a job array's task).
    pub index: usize,
    /// Its stable id, the name of its output folder.
    pub id: String,
    /// Its entry in the manifest's `inputs`.
    pub input: usize,
    /// Its entry in the manifest's `styles`.
    pub style: usize,
    /// A short name of its input (a file name).
    pub input_label: String,
    /// A short name of its style (the prompt, or the picture's file name).
    pub style_label: String,
    /// The modality's whole configuration, without `out`.
    pub config: Value,
}

impl Job {
    /// The job's output folder in the batch folder `dir`.
    pub fn out(&self, dir: &Path) -> PathBuf {
        dir.join(&self.id)
    }

    /// The job's configuration writing into `dir`'s folder of the job.
    pub fn config_in(&self, dir: &Path) -> Value {
        let mut config = self.config.clone();
        config["out"] = Value::String(self.out(dir).display().to_string());
        config
    }

    /// The steps the job's stylization takes.
    pub fn steps(&self) -> u64 {
        self.config["steps"].as_u64().unwrap_or(0)
    }
}

/// Plans the manifest at `manifest_path` into the batch folder `dir` (created): checks every
/// entry, writes `jobs.json` and returns the plan.
pub fn plan(manifest_path: &Path, dir: &Path) -> Result<Plan, String> {
    let manifest_path = std::path::absolute(manifest_path)
        .map_err(|e| format!("{}: {e}", manifest_path.display()))?;
    let manifest = manifest::read(&manifest_path)?;
    let folder = manifest_path.parent().unwrap_or(Path::new("."));
    let configs = manifest::expand(&manifest, folder)
        .map_err(|e| format!("manifest {}: {e}", manifest_path.display()))?;
    let mut jobs: Vec<Job> = Vec::with_capacity(configs.len());
    // Each id's job, so a repeated job is found in constant time (a scan made plans of
    // 70k jobs take 35 s).
    let mut seen: HashMap<String, usize> = HashMap::with_capacity(configs.len());
    let mut checked_paths = HashSet::new();
    for (index, mut c) in configs.into_iter().enumerate() {
        // Paths a configuration file gives are taken from the working folder, as the binaries
        // take them; the tasks may run elsewhere.
        for field in PATH_FIELDS {
            if let Some(path) = c.config[field].as_str() {
                let absolute = std::path::absolute(path).map_err(|e| format!("{field}: {e}"))?;
                // A configuration file's paths, the same for many jobs: each checked once.
                if checked_paths.insert((field, absolute.clone())) {
                    manifest
                        .modality
                        .check_path(field, &absolute)
                        .map_err(|e| format!("config {field}: {e}"))?;
                }
                c.config[field] = Value::String(absolute.display().to_string());
            }
        }
        // As the job's run would check it (its output folder is not known yet: any will do).
        let mut checked = c.config.clone();
        checked["out"] = Value::String(dir.join("job").display().to_string());
        manifest.modality.check(&checked).map_err(|e| {
            format!(
                "manifest {}: inputs[{}] with styles[{}]: {e}",
                manifest_path.display(),
                c.input,
                c.style
            )
        })?;
        let id = job_id(manifest.modality, &c.config)?;
        if let Some(&same) = seen.get(&id) {
            let same = &jobs[same];
            return Err(format!(
                "manifest {}: inputs[{}] with styles[{}] is the same job as inputs[{}] with \
                 styles[{}]",
                manifest_path.display(),
                c.input,
                c.style,
                same.input,
                same.style
            ));
        }
        seen.insert(id.clone(), index);
        jobs.push(Job {
            index,
            id,
            input: c.input,
            style: c.style,
            input_label: label(&format!("inputs[{}]", c.input), &manifest.inputs[c.input]),
            style_label: label(&format!("styles[{}]", c.style), &manifest.styles[c.style]),
            config: c.config,
        });
    }
    let eval = manifest
        .eval
        .as_ref()
        .map(|e| e.resolved(folder))
        .transpose()
        .map_err(|e| format!("manifest {}: {e}", manifest_path.display()))?;
    let plan = Plan {
        manifest: manifest_path.clone(),
        modality: manifest.modality,
        inputs: manifest.inputs.len(),
        styles: manifest.styles.len(),
        jobs,
        eval,
    };
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    write_json(&dir.join(JOBS_JSON), &plan).map_err(|e| e.to_string())?;
    Ok(plan)
}

/// The plan of the batch folder `dir`.
pub fn read(dir: &Path) -> Result<Plan, String> {
    let path = dir.join(JOBS_JSON);
    let text = std::fs::read_to_string(&path).map_err(|e| {
        format!(
            "{}: {e} (plan the batch first: clipgaussian batch plan MANIFEST --out {})",
            path.display(),
            dir.display()
        )
    })?;
    let plan: Plan = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    plan.check()
        .map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(plan)
}

/// Bytes of the hash a job id is the hexadecimal of.
const ID_BYTES: usize = 8;

/// Refuses `id` unless it is a job id as [`plan`] makes them: [`ID_BYTES`] x 2 lowercase
/// hexadecimal digits. An id is a folder's and a file's name in the batch folder, so nothing
/// else (`..`, `/`, an absolute path) may reach a path.
pub fn check_id(id: &str) -> Result<(), String> {
    let hex = |b: u8| b.is_ascii_digit() || (b'a'..=b'f').contains(&b);
    if id.len() == 2 * ID_BYTES && id.bytes().all(hex) {
        return Ok(());
    }
    Err(format!(
        "{id:?} is not a job id ({} lowercase hexadecimal digits, as `batch plan` writes them); \
         plan the batch again",
        2 * ID_BYTES
    ))
}

impl Plan {
    /// Refuses a plan `batch plan` could not have written: an entry whose index is not its
    /// place, an id that is not one ([`check_id`]), or an id two entries share (they would
    /// share a folder).
    fn check(&self) -> Result<(), String> {
        let mut seen = HashMap::with_capacity(self.jobs.len());
        for (k, job) in self.jobs.iter().enumerate() {
            if job.index != k {
                return Err(format!(
                    "jobs[{k}].index: {} (the entry is number {k})",
                    job.index
                ));
            }
            check_id(&job.id).map_err(|e| format!("jobs[{k}].id: {e}"))?;
            if let Some(j) = seen.insert(job.id.as_str(), k) {
                return Err(format!("jobs[{k}].id: {} is also jobs[{j}]'s", job.id));
            }
        }
        Ok(())
    }
}

/// Adds the path, size and modification time of `path` to `files`, and of every file under it
/// when it is a folder (a dataset, a video's frames), in name order.
fn stamp_files(path: &Path, field: &str, files: &mut Vec<Value>) -> std::io::Result<()> {
    let meta = std::fs::metadata(path)?;
    let modified = meta
        .modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_nanos());
    files.push(json!([field, path, meta.len(), modified.to_string()]));
    if meta.is_dir() {
        let mut entries: Vec<PathBuf> = std::fs::read_dir(path)?
            .map(|e| e.map(|e| e.path()))
            .collect::<Result<_, _>>()?;
        entries.sort();
        for entry in entries {
            stamp_files(&entry, field, files)?;
        }
    }
    Ok(())
}

/// The id of a job of `modality` with `config`: the first 16 hexadecimal digits of a SHA-256
/// of both and of the path, size and modification time of every file it names (every file
/// under a folder it names).
fn job_id(modality: ModalityKind, config: &Value) -> Result<String, String> {
    let mut files = Vec::new();
    for field in PATH_FIELDS {
        if let Some(path) = config[field].as_str() {
            stamp_files(Path::new(path), field, &mut files)
                .map_err(|e| format!("{field}: {path}: {e}"))?;
        }
    }
    let identity = json!({"modality": modality.name(), "config": config, "files": files});
    Ok(short_hash(
        &serde_json::to_vec(&identity).expect("JSON serializes"),
        ID_BYTES,
    ))
}

/// The first `bytes` bytes of the SHA-256 of `data`, in hexadecimal.
pub fn short_hash(data: &[u8], bytes: usize) -> String {
    Sha256::digest(data)[..bytes]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}
