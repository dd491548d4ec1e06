//! The summary of a finished stylization: printed at the end and written as `summary.json` in
//! its output folder, so that a user (or a batch script) sees at once how long it took, how far
//! it went and where the outputs are.

use std::path::Path;
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::checkpoint::checkpoint_dir;
use crate::outputs::{read_json, write_json, FitReport, StepLosses, FIT_JSON, LOSSES_JSON};
use crate::progress::clock;
use crate::StylizeError;

/// The summary file in the output folder.
pub const SUMMARY_JSON: &str = "summary.json";

/// What `summary.json` holds.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RunReport {
    /// The binary and subcommand, e.g. `clipgaussian-2d stylize`.
    pub command: String,
    /// Wall time of this process's run, seconds.
    pub seconds: f64,
    /// Optimizer steps taken, resumed ones included (from `losses.json`; 0 without it).
    pub steps: u64,
    /// The last step's total loss.
    pub final_loss: Option<f32>,
    /// The output folder.
    pub out: String,
    /// Its files and folders (top level, sorted), without the checkpoint and this file.
    pub outputs: Vec<String>,
    /// What the fit of the base model did, when the run fitted it (its `fit.json`).
    pub fit: Option<FitReport>,
}

/// Writes `summary.json` in `out` for the run of `command` started at `started`, and returns
/// the lines to print: the wall time, the steps and final loss, and the outputs.
pub fn write_summary(command: &str, started: Instant, out: &Path) -> Result<String, StylizeError> {
    let losses: Vec<StepLosses> = read_json(&out.join(LOSSES_JSON)).unwrap_or_default();
    let checkpoint = checkpoint_dir(out);
    let mut outputs: Vec<String> = std::fs::read_dir(out)
        .map_err(|source| StylizeError::Io {
            path: out.to_path_buf(),
            source,
        })?
        .filter_map(|entry| entry.ok())
        .filter(|entry| entry.path() != checkpoint)
        .map(|entry| entry.file_name().to_string_lossy().into_owned())
        .filter(|name| name != SUMMARY_JSON && !name.ends_with(".tmp"))
        .collect();
    outputs.sort();
    let report = RunReport {
        command: command.to_string(),
        seconds: started.elapsed().as_secs_f64(),
        steps: losses.last().map_or(0, |l| l.step),
        final_loss: losses.last().map(|l| l.total),
        out: out.display().to_string(),
        outputs,
        fit: read_json(&out.join(FIT_JSON)).ok(),
    };
    write_json(&out.join(SUMMARY_JSON), &report)?;
    Ok(lines(&report))
}

/// `done in 0:01:23: 6 steps, final loss 0.1234`, the fit's line when the run fitted its base
/// model (`base model fitted in 0:00:44 (3000 steps), PSNR 31.20 dB`) and the outputs, one
/// line each.
fn lines(report: &RunReport) -> String {
    let clock_of = |seconds: f64| clock(Duration::from_secs(seconds.max(0.0).round() as u64));
    let loss = report
        .final_loss
        .map_or(String::new(), |l| format!(", final loss {l:.4}"));
    let fit = report.fit.as_ref().map_or(String::new(), |fit| {
        let psnr = fit
            .psnr_db
            .map_or(String::new(), |db| format!(", PSNR {db:.2} dB"));
        format!(
            "base model fitted in {} ({} steps){psnr}\n",
            clock_of(fit.seconds),
            fit.steps
        )
    });
    format!(
        "done in {}: {} steps{loss}\n{fit}outputs in {}: {}, {SUMMARY_JSON}\n",
        clock_of(report.seconds),
        report.steps,
        report.out,
        report.outputs.join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_summary_lists_the_outputs_and_reads_the_last_step() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        std::fs::write(out.join("stylized.png"), b"png").unwrap();
        std::fs::create_dir_all(out.join("frames")).unwrap();
        std::fs::create_dir_all(checkpoint_dir(out)).unwrap();
        let losses = vec![
            StepLosses {
                step: 1,
                view: 0,
                total: 0.5,
                terms: Default::default(),
            },
            StepLosses {
                step: 2,
                view: 1,
                total: 0.25,
                terms: Default::default(),
            },
        ];
        write_json(&out.join(LOSSES_JSON), &losses).unwrap();
        let text = write_summary("clipgaussian-2d stylize", Instant::now(), out).unwrap();
        assert!(
            text.starts_with("done in 0:00:00: 2 steps, final loss 0.2500\n"),
            "{text}"
        );
        assert!(
            text.contains(": frames, losses.json, stylized.png, summary.json"),
            "{text}"
        );
        let written: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join(SUMMARY_JSON)).unwrap())
                .unwrap();
        assert_eq!(written["command"], "clipgaussian-2d stylize");
        assert_eq!(written["steps"], 2);
        assert_eq!(
            written["outputs"],
            serde_json::json!(["frames", "losses.json", "stylized.png"])
        );
        assert_eq!(written["fit"], serde_json::Value::Null);

        let fit = FitReport {
            steps: 3000,
            seconds: 44.4,
            psnr_db: Some(31.204),
            gaussians: None,
            test_psnr_db: None,
        };
        write_json(&out.join(FIT_JSON), &fit).unwrap();
        let text = write_summary("clipgaussian-2d stylize", Instant::now(), out).unwrap();
        assert!(
            text.contains("\nbase model fitted in 0:00:44 (3000 steps), PSNR 31.20 dB\noutputs"),
            "{text}"
        );
        assert!(text.contains("fit.json, frames"), "{text}");
        let written: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join(SUMMARY_JSON)).unwrap())
                .unwrap();
        assert_eq!(written["fit"]["psnr_db"], 31.204);
    }
}
