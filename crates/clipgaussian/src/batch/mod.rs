//! `clipgaussian batch`: many stylizations (inputs x styles) from one manifest, run here or
//! by a cluster's own scheduler, one job per index.
//!
//! - [`manifest`]: the manifest file and its expansion into jobs;
//! - [`plan`]: `jobs.json`, each job's stable id and output folder;
//! - [`modality`]: a job's configuration and run, by modality (the modality crates' own run
//!   functions, in this process);
//! - [`job`]: running one job by index (skip when done, resume when interrupted) and its
//!   exit code, and running every job here, several at once;
//! - [`status`] and [`collect`]: where the batch stands, and its results gathered;
//! - [`scheduler`]: the Slurm job-array script and the Kubernetes Indexed Job.

pub mod collect;
pub mod job;
pub mod manifest;
pub mod modality;
pub mod plan;
pub mod scheduler;
pub mod status;
