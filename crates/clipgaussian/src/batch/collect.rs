//! A batch's results gathered: `results.json` and `results.csv` (one row per job: id, input,
//! style, status, wall time, steps, final losses, the metrics of its `metrics.json` when the
//! manifest asked for them, output folder) and `contact_sheet.png`
//! (every finished job's before/after preview under its label, one row per input, one column
//! per style).

use std::path::Path;

use gs_stylize::evaluation::METRICS_JSON;
use gs_stylize::outputs::{read_json, write_json, StepLosses, LOSSES_JSON, PREVIEW_PNG};
use gs_stylize::plot::label_strip;
use serde::Serialize;
use serde_json::{Map, Value};

use super::job::read_state;
use super::plan::{self, Plan};
use super::status::job_status;

/// The results' files in the batch folder.
pub const RESULTS_JSON: &str = "results.json";
/// See [`RESULTS_JSON`].
pub const RESULTS_CSV: &str = "results.csv";
/// See [`RESULTS_JSON`].
pub const CONTACT_SHEET_PNG: &str = "contact_sheet.png";

/// Width of a preview in the contact sheet, pixels.
const CELL_WIDTH: u32 = 320;
/// Height of a preview's label in the contact sheet, pixels.
const LABEL_HEIGHT: u32 = 20;

/// One job's row.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct JobResult {
    /// Its index.
    pub index: usize,
    /// Its id.
    pub id: String,
    /// Its input (a short name).
    pub input: String,
    /// Its style (the prompt or the picture's name).
    pub style: String,
    /// `done`, `running`, `failed`, `stopped` or `left`.
    pub status: String,
    /// Wall time of its last run, seconds.
    pub seconds: Option<f64>,
    /// Steps it took.
    pub steps: Option<u64>,
    /// Its final total loss.
    pub final_loss: Option<f32>,
    /// Its final loss terms (weighted), by name.
    pub final_terms: std::collections::BTreeMap<String, f32>,
    /// Its scores (`metrics.json`: the CLIP metrics, and a video's temporal consistency),
    /// when the manifest asked for them and they are written.
    pub metrics: Option<Map<String, Value>>,
    /// Its output folder.
    pub out: String,
    /// Its before/after picture, when written.
    pub preview: Option<String>,
}

/// The rows of the batch in `dir`.
pub fn results(dir: &Path, plan: &Plan) -> Vec<JobResult> {
    plan.jobs
        .iter()
        .map(|job| {
            let out = job.out(dir);
            let losses: Option<Vec<StepLosses>> = read_json(&out.join(LOSSES_JSON)).ok();
            let last = losses.as_ref().and_then(|l| l.last());
            let preview = out.join(PREVIEW_PNG);
            JobResult {
                index: job.index,
                id: job.id.clone(),
                input: job.input_label.clone(),
                style: job.style_label.clone(),
                status: job_status(dir, plan, job).word().into(),
                seconds: read_state(dir, job).and_then(|s| s.seconds),
                steps: last.map(|l| l.step),
                final_loss: last.map(|l| l.total),
                final_terms: last.map(|l| l.terms.clone()).unwrap_or_default(),
                metrics: read_json(&out.join(METRICS_JSON)).ok(),
                out: out.display().to_string(),
                preview: preview.is_file().then(|| preview.display().to_string()),
            }
        })
        .collect()
}

/// Writes `results.json`, `results.csv` and `contact_sheet.png` into the batch folder `dir`;
/// returns the line that says so.
pub fn collect(dir: &Path) -> Result<String, String> {
    let plan = plan::read(dir)?;
    let rows = results(dir, &plan);
    let write = |name: &str, bytes: &[u8]| {
        let path = dir.join(name);
        gs_core::fs::write_atomic(&path, bytes).map_err(|e| format!("{}: {e}", path.display()))
    };
    write_json(&dir.join(RESULTS_JSON), &rows).map_err(|e| e.to_string())?;
    write(RESULTS_CSV, csv(&rows, plan.eval.is_some()).as_bytes())?;
    let mut png = std::io::Cursor::new(Vec::new());
    contact_sheet(&plan, &rows)?
        .write_to(&mut png, image::ImageFormat::Png)
        .map_err(|e| e.to_string())?;
    write(CONTACT_SHEET_PNG, png.get_ref())?;
    let path = dir.join(CONTACT_SHEET_PNG);
    let done = rows.iter().filter(|r| r.status == "done").count();
    Ok(format!(
        "{} jobs ({done} done): wrote {}, {} and {}",
        rows.len(),
        dir.join(RESULTS_JSON).display(),
        dir.join(RESULTS_CSV).display(),
        path.display()
    ))
}

/// The rows as CSV: a header, then one line per job; the terms are the loss terms every
/// modality has; with `metrics`, a column for each score any job wrote (the CLIP metrics in
/// the paper's order, then any other by name; empty where a job has none).
fn csv(rows: &[JobResult], metrics: bool) -> String {
    const TERMS: [&str; 4] = ["directional", "patch", "content", "background"];
    const CLIP_METRICS: [&str; 5] = ["views", "clip_s", "clip_sim", "clip_cons", "clip_f"];
    let quote = |s: &str| format!("\"{}\"", s.replace('"', "\"\""));
    let number = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
    let mut scores: Vec<&str> = Vec::new();
    if metrics {
        for name in rows
            .iter()
            .flat_map(|r| r.metrics.iter().flat_map(|m| m.keys()))
        {
            if !scores.contains(&name.as_str()) {
                scores.push(name);
            }
        }
    }
    scores.sort_by_key(|s| {
        let known = CLIP_METRICS.iter().position(|m| m == s);
        (known.unwrap_or(CLIP_METRICS.len()), *s)
    });
    let mut text = format!(
        "index,id,input,style,status,seconds,steps,final_loss,{},{}out,preview\n",
        TERMS.join(","),
        scores.iter().map(|s| format!("{s},")).collect::<String>()
    );
    for r in rows {
        let terms: Vec<String> = TERMS
            .iter()
            .map(|t| number(r.final_terms.get(*t).map(|&v| f64::from(v))))
            .collect();
        let values: String = scores
            .iter()
            .map(|s| {
                let value = r.metrics.as_ref().and_then(|m| m.get(*s));
                format!("{},", number(value.and_then(Value::as_f64)))
            })
            .collect();
        text += &format!(
            "{},{},{},{},{},{},{},{},{},{values}{},{}\n",
            r.index,
            r.id,
            quote(&r.input),
            quote(&r.style),
            r.status,
            number(r.seconds),
            r.steps.map_or(String::new(), |s| s.to_string()),
            number(r.final_loss.map(f64::from)),
            terms.join(","),
            quote(&r.out),
            quote(r.preview.as_deref().unwrap_or(""))
        );
    }
    text
}

/// Every finished job's preview scaled to [`CELL_WIDTH`] under a label (`index: input x
/// style`), in a grid of the manifest's inputs (rows) by styles (columns) for a cross product,
/// else one row; a job without a preview is a grey cell.
fn contact_sheet(plan: &Plan, rows: &[JobResult]) -> Result<image::RgbImage, String> {
    let cross = plan.jobs.len() == plan.inputs * plan.styles;
    let (grid_rows, grid_cols) = if cross {
        (plan.inputs, plan.styles)
    } else {
        (1, plan.jobs.len())
    };
    let previews: Vec<Option<image::RgbImage>> = rows
        .iter()
        .map(|r| {
            let path = r.preview.as_ref()?;
            let picture = gs_core::image::decode_picture(std::path::Path::new(path))
                .ok()?
                .to_rgb8();
            let height = (u64::from(picture.height()) * u64::from(CELL_WIDTH)
                / u64::from(picture.width().max(1)))
            .max(1) as u32;
            Some(image::imageops::resize(
                &picture,
                CELL_WIDTH,
                height,
                image::imageops::FilterType::Triangle,
            ))
        })
        .collect();
    let picture_height = previews
        .iter()
        .flatten()
        .map(|p| p.height())
        .max()
        .unwrap_or(CELL_WIDTH / 2);
    let cell_height = LABEL_HEIGHT + picture_height;
    let mut sheet = image::RgbImage::from_pixel(
        CELL_WIDTH * grid_cols as u32,
        cell_height * grid_rows as u32,
        image::Rgb([96, 96, 96]),
    );
    for ((job, row), preview) in plan.jobs.iter().zip(rows).zip(&previews) {
        let (r, c) = if cross {
            (job.input, job.style)
        } else {
            (0, job.index)
        };
        let (x, y) = (
            i64::from(CELL_WIDTH * c as u32),
            i64::from(cell_height * r as u32),
        );
        let text = format!(
            "{}: {} x {} ({})",
            job.index, job.input_label, job.style_label, row.status
        );
        let label = label_strip(CELL_WIDTH, LABEL_HEIGHT, &text).map_err(|e| e.to_string())?;
        image::imageops::overlay(&mut sheet, &label, x, y);
        if let Some(p) = preview {
            image::imageops::overlay(&mut sheet, p, x, y + i64::from(LABEL_HEIGHT));
        }
    }
    Ok(sheet)
}
