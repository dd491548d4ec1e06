//! `clipgaussian batch` end to end on 2 pictures x 2 styles with the tiny models: plan, run two
//! at once, an interrupted job finished by running the batch again (with the results of an
//! uninterrupted run), each job's metrics those of the 2D eval and scored again (not stylized
//! again) when lost, status and collect agreeing with the folders, the scheduler files, and a
//! bad manifest refused at plan naming its entry and field.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use gs_stylize::evaluation::{ClipFiles, Scoring, Style};

// The example that writes the tiny batch; its `main` is the example's own.
#[allow(dead_code)]
#[path = "../examples/tiny_batch.rs"]
mod tiny_batch;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_clipgaussian"))
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().unwrap()
}

fn succeeds(args: &[&str]) -> String {
    let out = run(args);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "{args:?}: {stdout}\n{stderr}");
    stdout.into_owned()
}

/// The tiny batch of 2 pictures x 2 styles (a prompt and a picture), `steps` steps a job, the
/// tiny models, written into `dir`; its manifest's path.
fn manifest(dir: &Path, steps: u64) -> PathBuf {
    tiny_batch::write(dir, steps).unwrap()
}

fn jobs(batch: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(batch.join("jobs.json")).unwrap()).unwrap()
}

/// Runs job `index` of `batch` and sends it `signal` (`-TERM`, `-KILL`) once its output `out`
/// holds a checkpoint; returns how it ended.
fn interrupted(batch: &Path, index: usize, out: &Path, signal: &str) -> std::process::ExitStatus {
    let mut child = bin()
        .args([
            "batch",
            "run",
            s(batch),
            "--index",
            &index.to_string(),
            "--quiet",
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    while !out.join("checkpoint/state.json").exists() {
        if let Some(status) = child.try_wait().unwrap() {
            panic!("job {index} ended before its first checkpoint: {status}");
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let sent = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    child.wait().unwrap()
}

#[test]
fn a_batch_plans_runs_resumes_and_collects() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = manifest(dir.path(), 30);
    let batch = dir.path().join("batch");

    let line = succeeds(&["batch", "plan", s(&manifest), "--out", s(&batch)]);
    assert!(
        line.contains("planned 4 jobs (2 inputs x 2 styles, 0 already done)"),
        "{line}"
    );
    let planned = jobs(&batch);
    let ids: Vec<&str> = (0..4)
        .map(|i| planned["jobs"][i]["id"].as_str().unwrap())
        .collect();
    assert_eq!(
        ids.iter().collect::<std::collections::BTreeSet<_>>().len(),
        4,
        "{ids:?}"
    );
    assert_eq!(planned["jobs"][1]["style_label"], "starry.png");
    assert_eq!(planned["jobs"][2]["input_label"], "dog.png");
    succeeds(&["batch", "plan", s(&manifest), "--out", s(&batch)]);
    assert_eq!(
        jobs(&batch)["jobs"],
        planned["jobs"],
        "the same manifest plans the same ids"
    );

    // Job 3 interrupted after its first checkpoint: SIGTERM, a checkpoint, exit 75. Job 2
    // killed outright (SIGKILL): its state says running, its process is gone.
    let job3 = batch.join(ids[3]);
    let status = interrupted(&batch, 3, &job3, "-TERM");
    assert_eq!(
        status.code(),
        Some(75),
        "an interrupted job asks to be run again"
    );
    let status = interrupted(&batch, 2, &batch.join(ids[2]), "-KILL");
    assert_eq!(status.code(), None, "killed by a signal");
    let report = succeeds(&["batch", "status", s(&batch)]);
    assert!(
        report.contains("4 jobs: 0 done, 0 running, 0 failed, 2 stopped, 2 left"),
        "{report}"
    );

    // The whole batch, two at once: job 3 resumes, the others run.
    let line = succeeds(&[
        "batch",
        "run",
        s(&batch),
        "--parallel",
        "2",
        "--threads",
        "1",
    ]);
    assert!(
        line.contains("4 of 4 jobs to run, 2 at once, 1 threads each"),
        "{line}"
    );
    for index in [2, 3] {
        let log = std::fs::read_to_string(batch.join(format!("logs/{index}.log"))).unwrap();
        assert!(log.contains("resuming"), "{log}");
    }
    let report = succeeds(&["batch", "status", s(&batch)]);
    assert!(report.contains("4 jobs: 4 done"), "{report}");
    for id in &ids {
        assert!(batch.join(id).join("stylized.png").is_file(), "{id}");
    }
    // Run again: nothing left to do.
    let line = succeeds(&["batch", "run", s(&batch)]);
    assert!(line.contains("0 of 4 jobs to run"), "{line}");

    // The resumed job ends where an uninterrupted one does.
    let fresh = dir.path().join("fresh");
    succeeds(&["batch", "plan", s(&manifest), "--out", s(&fresh)]);
    succeeds(&["batch", "run", s(&fresh), "--index", "3", "--quiet"]);
    assert_eq!(
        std::fs::read(fresh.join(ids[3]).join("model.ply")).unwrap(),
        std::fs::read(job3.join("model.ply")).unwrap(),
        "a resumed job gives the uninterrupted job's model"
    );

    // Collect: one row per job, agreeing with status; a contact sheet of 2 x 2 previews.
    let line = succeeds(&["batch", "collect", s(&batch)]);
    assert!(line.contains("4 jobs (4 done)"), "{line}");
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(batch.join("results.json")).unwrap())
            .unwrap();
    for (i, row) in results.as_array().unwrap().iter().enumerate() {
        assert_eq!(row["id"], ids[i]);
        assert_eq!(row["status"], "done");
        assert_eq!(row["steps"], 30);
        assert!(row["final_loss"].as_f64().unwrap().is_finite(), "{row}");
        assert!(row["preview"].as_str().unwrap().ends_with("preview.png"));
        // The metrics are the 2D eval's of the stylized picture against its input.
        let job = &planned["jobs"][i];
        let style = match job["config"]["style_image"].as_str() {
            Some(image) => Style::Image(image.into()),
            None => Style::Prompt(job["config"]["style_prompt"].as_str().unwrap().into()),
        };
        let models = &job["config"];
        let path = |key: &str| Some(PathBuf::from(models[key].as_str().unwrap()));
        let scoring = Scoring {
            style,
            source_prompt: models["source_prompt"].as_str().unwrap().into(),
            clip: ClipFiles {
                config: path("clip_config"),
                weights: path("clip_weights"),
                tokenizer: path("tokenizer"),
            },
        };
        let expected = base_mirage::evaluation::evaluate_picture(
            &batch.join(ids[i]).join("stylized.png"),
            &dir.path().join(job["input_label"].as_str().unwrap()),
            [0.0; 3],
            &scoring,
        )
        .unwrap();
        assert_eq!(row["metrics"], serde_json::to_value(&expected).unwrap());
        assert_eq!(row["metrics"]["views"], 1);
        assert!(row["metrics"]["clip_s"].as_f64().unwrap().is_finite());
    }
    // Metrics lost: the job is left, and running it scores it again without stylizing again.
    let model = job3.join("model.ply");
    let modified = std::fs::metadata(&model).unwrap().modified().unwrap();
    let metrics = std::fs::read(job3.join("metrics.json")).unwrap();
    std::fs::remove_file(job3.join("metrics.json")).unwrap();
    let report = succeeds(&["batch", "status", s(&batch)]);
    assert!(report.contains("4 jobs: 3 done, 0 running, 0 failed, 0 stopped, 1 left"));
    let line = succeeds(&["batch", "run", s(&batch), "--index", "3", "--quiet"]);
    assert!(line.contains("stylized; scoring"), "{line}");
    assert_eq!(std::fs::read(job3.join("metrics.json")).unwrap(), metrics);
    assert_eq!(
        std::fs::metadata(&model).unwrap().modified().unwrap(),
        modified,
        "not stylized again"
    );
    let csv = std::fs::read_to_string(batch.join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 5, "{csv}");
    assert!(
        csv.lines()
            .next()
            .unwrap()
            .contains(",views,clip_s,clip_sim,clip_cons,clip_f,"),
        "{csv}"
    );
    assert!(
        csv.lines().nth(2).unwrap().contains("\"starry.png\",done"),
        "{csv}"
    );
    let (w, h) = image::image_dimensions(batch.join("contact_sheet.png")).unwrap();
    let (pw, ph) = image::image_dimensions(job3.join("preview.png")).unwrap();
    assert_eq!(
        (w, h),
        (640, 2 * (20 + ph * 320 / pw)),
        "2 styles across, 2 inputs down, each under its label"
    );
}

#[test]
fn the_scheduler_files_hold_the_array_and_the_retry_rules() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = manifest(dir.path(), 2);
    let batch = dir.path().join("batch");
    succeeds(&["batch", "plan", s(&manifest), "--out", s(&batch)]);

    // A task's index comes from the scheduler's environment: only that job runs.
    for (variable, index) in [("SLURM_ARRAY_TASK_ID", 1), ("JOB_COMPLETION_INDEX", 2)] {
        let out = bin()
            .args(["batch", "run", s(&batch), "--quiet"])
            .env(variable, index.to_string())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let report = succeeds(&["batch", "status", s(&batch)]);
    assert!(
        report.contains("4 jobs: 2 done, 0 running, 0 failed, 0 stopped, 2 left"),
        "{report}"
    );
    let done: Vec<&str> = report.lines().filter(|l| l.contains(" done ")).collect();
    assert!(
        done[0].trim_start().starts_with("1 ") && done[1].trim_start().starts_with("2 "),
        "{report}"
    );

    succeeds(&[
        "batch",
        "slurm",
        s(&batch),
        "--parallel",
        "2",
        "--partition",
        "gpu",
    ]);
    let script = batch.join("batch.sbatch");
    let text = std::fs::read_to_string(&script).unwrap();
    for part in [
        "#SBATCH --array=0-3%2",
        "#SBATCH --requeue",
        "#SBATCH --ntasks=1",
        "#SBATCH --signal=B:USR1@120",
        "trap ':' TERM",
        "#SBATCH --gpus-per-task=1",
        "#SBATCH --partition=gpu",
        "--index \"$SLURM_ARRAY_TASK_ID\"",
        "if [ \"$rc\" -eq 75 ]; then",
        "scontrol requeue",
    ] {
        assert!(text.contains(part), "{part} not in:\n{text}");
    }
    assert!(
        batch.join("logs").is_dir(),
        "Slurm opens the tasks' logs there before they run"
    );
    let syntax = Command::new("bash")
        .arg("-n")
        .arg(&script)
        .status()
        .unwrap();
    assert!(syntax.success(), "bash -n {}", script.display());

    succeeds(&[
        "batch",
        "k8s",
        s(&batch),
        "--image",
        "ghcr.io/x/clipgaussian:1",
        "--parallel",
        "3",
    ]);
    let text = std::fs::read_to_string(batch.join("batch-job.yaml")).unwrap();
    let job: serde_json::Value = serde_yaml_ng::from_str(&text).unwrap();
    let spec = &job["spec"];
    assert_eq!(job["kind"], "Job");
    assert_eq!(spec["completionMode"], "Indexed");
    assert_eq!(spec["completions"], 4);
    assert_eq!(spec["parallelism"], 3);
    assert_eq!(spec["backoffLimitPerIndex"], 3);
    let rule = &spec["podFailurePolicy"]["rules"][0];
    assert_eq!(rule["action"], "FailIndex");
    assert_eq!(rule["onExitCodes"]["values"][0], 65);
    let pod = &spec["template"]["spec"];
    assert_eq!(pod["restartPolicy"], "Never");
    let container = &pod["containers"][0];
    assert_eq!(container["resources"]["limits"]["nvidia.com/gpu"], 1);
    assert_eq!(container["command"][3], s(&batch));
    // The batch folder is inside the manifest's: one mount, of the manifest's folder.
    assert_eq!(container["volumeMounts"].as_array().unwrap().len(), 1);
    assert_eq!(container["volumeMounts"][0]["mountPath"], s(dir.path()));
    assert_eq!(pod["volumes"][0]["hostPath"]["path"], s(dir.path()));
    let name = job["metadata"]["name"].as_str().unwrap().to_string();
    assert!(name.starts_with("clipgaussian-2d-"), "{name}");

    // A batch folder elsewhere: mounted beside the manifest's folder (read-only), and a Job of
    // another name.
    let elsewhere = tempfile::tempdir().unwrap();
    let other = elsewhere.path().join("batch");
    succeeds(&["batch", "plan", s(&manifest), "--out", s(&other)]);
    succeeds(&["batch", "k8s", s(&other), "--image", "x", "--claim", "runs"]);
    let text = std::fs::read_to_string(other.join("batch-job.yaml")).unwrap();
    let job: serde_json::Value = serde_yaml_ng::from_str(&text).unwrap();
    let pod = &job["spec"]["template"]["spec"];
    let mounts = &pod["containers"][0]["volumeMounts"];
    assert_eq!(mounts[0]["mountPath"], s(&other));
    assert_eq!(mounts[1]["mountPath"], s(dir.path()));
    assert_eq!(mounts[1]["readOnly"], true);
    assert_eq!(
        pod["volumes"][0]["persistentVolumeClaim"]["claimName"],
        "runs"
    );
    assert_eq!(pod["volumes"][1]["hostPath"]["path"], s(dir.path()));
    assert_ne!(job["metadata"]["name"], name.as_str());
}

#[test]
fn a_bad_manifest_entry_is_refused_at_plan_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = manifest(dir.path(), 2);
    let good: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let batch = dir.path().join("batch");
    // Files that exist but are not of their kind, and settings the job's run would refuse.
    std::fs::create_dir(dir.path().join("a-folder")).unwrap();
    std::fs::write(dir.path().join("text.png"), "not a picture").unwrap();
    let cases: [(&str, serde_json::Value, &str); 16] = [
        (
            "/inputs/1/picture",
            "missing.png".into(),
            "inputs[1].picture: ",
        ),
        (
            "/inputs/1/picture",
            "/dev/zero".into(),
            "inputs[1].picture: /dev/zero is not a regular file",
        ),
        (
            "/inputs/0/picture",
            "text.png".into(),
            "inputs[0].picture: ",
        ),
        (
            "/styles/1/style_image",
            "a-folder".into(),
            "a-folder is a folder, not a file",
        ),
        ("/set/clip_weights", "text.png".into(), "set.clip_weights: "),
        (
            "/set/tokenizer",
            "/dev/zero".into(),
            "set.tokenizer: /dev/zero is not a regular file",
        ),
        (
            "/set/learning_rates",
            serde_json::json!({"colour": 0.1}),
            "inputs[0] with styles[0]: ",
        ),
        ("/set/patch_size", 0.into(), "patch_size"),
        ("/styles/0/style_prompt", "  ".into(), "prompt"),
        ("/styles/0/bogus", 1.into(), "styles[0]: "),
        ("/inputs/0/fit_steps", "many".into(), "inputs[0]: "),
        (
            "/styles/1/style_prompt",
            "and a prompt".into(),
            "styles[1]: give style_prompt or style_image, not both",
        ),
        ("/set/out", "elsewhere".into(), "set.out: the batch chooses"),
        ("/pairing", "pairs".into(), "as many of each"),
        (
            "/eval/clip_weights",
            "missing.safetensors".into(),
            "eval.clip_weights: ",
        ),
        (
            "/eval/clip_model",
            "L/14".into(),
            "unknown field `clip_model`",
        ),
    ];
    for (pointer, value, expected) in cases {
        let mut bad = good.clone();
        let (parent, key) = pointer.rsplit_once('/').unwrap();
        let target = if parent.is_empty() {
            &mut bad
        } else {
            bad.pointer_mut(parent).unwrap()
        };
        target[key] = value.clone();
        if pointer == "/pairing" {
            bad["styles"].as_array_mut().unwrap().pop();
        }
        std::fs::write(&path, bad.to_string()).unwrap();
        let out = run(&["batch", "plan", s(&path), "--out", s(&batch)]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(65), "{pointer} {value}: {stderr}");
        assert!(
            stderr.contains(expected) && stderr.contains("manifest.json"),
            "{pointer}: {stderr}"
        );
        assert!(
            !batch.join("jobs.json").exists(),
            "{pointer}: nothing planned"
        );
    }
}

/// A 3D job with a dataset and no model is planned (its run fits the scene first); one with
/// neither is refused at plan, as its run would refuse it.
#[test]
fn a_3d_input_without_a_model_fits_first_and_without_data_is_refused_at_plan() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    std::fs::create_dir(&scene).unwrap();
    let plan = |input: serde_json::Value, name: &str| {
        let path = dir.path().join(format!("{name}.json"));
        let manifest = serde_json::json!({
            "modality": "3d",
            "inputs": [input],
            "styles": [{"style_prompt": "fire"}],
        });
        std::fs::write(&path, manifest.to_string()).unwrap();
        let batch = dir.path().join(name);
        (run(&["batch", "plan", s(&path), "--out", s(&batch)]), batch)
    };
    let (out, batch) = plan(serde_json::json!({"data": "scene"}), "fits");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(batch.join("jobs.json").is_file());
    let (out, batch) = plan(serde_json::json!({"orbit_views": 8}), "nothing");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(65), "{stderr}");
    assert!(
        stderr.contains("inputs[0] with styles[0]: ") && stderr.contains("model: is required"),
        "{stderr}"
    );
    assert!(!batch.join("jobs.json").exists());
}

/// A `jobs.json` edited so that an id would leave the batch folder (`..`, an absolute path),
/// or one no plan writes, is refused by run, status and collect naming the file and entry;
/// nothing is written outside.
#[test]
fn job_ids_that_are_not_ids_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = manifest(dir.path(), 2);
    let batch = dir.path().join("batch");
    succeeds(&["batch", "plan", s(&manifest), "--out", s(&batch)]);
    let planned = jobs(&batch);
    let escape = dir.path().join("escaped");
    let first = planned["jobs"][0]["id"].as_str().unwrap().to_string();
    for (id, said) in [
        (
            "../../escaped".to_string(),
            "jobs[0].id: \"../../escaped\" is not a job id",
        ),
        (s(&escape).to_string(), "is not a job id"),
        (first.to_uppercase(), "is not a job id"),
        (
            planned["jobs"][1]["id"].as_str().unwrap().into(),
            "is also jobs[0]'s",
        ),
    ] {
        let mut edited = planned.clone();
        edited["jobs"][0]["id"] = id.clone().into();
        std::fs::write(batch.join("jobs.json"), edited.to_string()).unwrap();
        for args in [
            vec!["batch", "run", s(&batch), "--index", "0", "--quiet"],
            vec!["batch", "status", s(&batch)],
            vec!["batch", "collect", s(&batch)],
        ] {
            let out = run(&args);
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert_ne!(out.status.code(), Some(0), "{id} {args:?}: {stderr}");
            assert!(
                stderr.contains("jobs.json") && stderr.contains(said),
                "{id} {args:?}: {stderr}"
            );
        }
    }
    assert!(!dir.path().join("escaped.lock").exists());
    assert!(!dir.path().join("escaped.json").exists());
    assert!(!escape.exists());
}

/// Reads every state file of `batch` and counts those that say running.
fn running_states(batch: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(batch.join("state")) else {
        return 0;
    };
    entries
        .filter_map(|e| std::fs::read_to_string(e.ok()?.path()).ok())
        .filter_map(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
        .filter(|state| state["status"] == "running")
        .count()
}

/// `--parallel 2` on the CPU runs two jobs at once; one stop, delivered to the batch's
/// process group as a terminal's Ctrl-C is, or to the batch and to every job as a scheduler
/// sends it, stops each running job once, with a checkpoint: exit 75, the jobs stopped (not
/// quit at once, not left running), and the batch run again resumes them.
#[test]
fn a_parallel_batch_runs_jobs_at_once_and_stops_them_once() {
    let dir = tempfile::tempdir().unwrap();
    // Steps enough that no job ends before the stop reaches it; stopped jobs take few of them.
    let manifest = manifest(dir.path(), 20_000);
    for delivery in ["group", "everyone"] {
        let batch = dir.path().join(delivery);
        succeeds(&["batch", "plan", s(&manifest), "--out", s(&batch)]);
        let planned = jobs(&batch);
        let mut child = {
            use std::os::unix::process::CommandExt;
            bin()
                .args([
                    "batch",
                    "run",
                    s(&batch),
                    "--parallel",
                    "2",
                    "--threads",
                    "1",
                ])
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .process_group(0)
                .spawn()
                .unwrap()
        };
        // Both first jobs hold a checkpoint, both running at once.
        let out = |i: usize| batch.join(planned["jobs"][i]["id"].as_str().unwrap());
        let mut both = false;
        while !(out(0).join("checkpoint/state.json").exists()
            && out(1).join("checkpoint/state.json").exists())
        {
            both |= running_states(&batch) == 2;
            assert!(child.try_wait().unwrap().is_none(), "the batch ended early");
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        both |= running_states(&batch) == 2;
        assert!(both, "two jobs ran at once");
        let pid = child.id().to_string();
        let kill = |args: &[&str]| {
            assert!(Command::new("kill").args(args).status().unwrap().success());
        };
        if delivery == "group" {
            kill(&["-INT", "--", &format!("-{pid}")]);
        } else {
            let pids: Vec<String> = (0..2)
                .map(|i| {
                    let state = batch.join(format!(
                        "state/{}.json",
                        planned["jobs"][i]["id"].as_str().unwrap()
                    ));
                    let state: serde_json::Value =
                        serde_json::from_str(&std::fs::read_to_string(state).unwrap()).unwrap();
                    state["pid"].to_string()
                })
                .collect();
            // A scheduler's SIGTERM to every process, and a SIGINT straight after (a signal
            // of another kind, so the kernel cannot merge it with the first): each job sees
            // two stops within the window, which are one.
            kill(&["-TERM", &pid, &pids[0], &pids[1]]);
            kill(&["-INT", &pids[0], &pids[1]]);
        }
        let output = child.wait_with_output().unwrap();
        let said = String::from_utf8_lossy(&output.stdout);
        assert_eq!(output.status.code(), Some(75), "{delivery}: {said}");
        assert!(
            said.matches("stopped (exit 75").count() == 2,
            "{delivery}: {said}"
        );
        let report = succeeds(&["batch", "status", s(&batch)]);
        assert!(report.contains("2 stopped, 2 left"), "{delivery}: {report}");
        for i in 0..2 {
            let state = batch.join(format!(
                "state/{}.json",
                planned["jobs"][i]["id"].as_str().unwrap()
            ));
            let state: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(state).unwrap()).unwrap();
            let reason = state["reason"].as_str().unwrap_or_default();
            assert!(
                state["exit_code"] == 75 && !reason.contains("quit at once"),
                "{delivery}: job {i} {state}"
            );
            assert!(out(i).join("checkpoint/state.json").is_file());
        }
    }
}

#[test]
fn the_example_manifest_plans() {
    let dir = tempfile::tempdir().unwrap();
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/batch-2d-example.json");
    let line = succeeds(&["batch", "plan", s(&example), "--out", s(dir.path())]);
    assert!(
        line.contains("planned 3 jobs (1 inputs x 3 styles"),
        "{line}"
    );
}

/// The sbatch script run by bash as Slurm would (its task's variables set, `scontrol` a stand-in
/// that records its arguments): Slurm's warning before the time limit (USR1 to the script), and
/// a cancel's SIGTERM to every process of the task, each reach the job as one SIGTERM: it stops
/// with a checkpoint, exits 75, and the script asks for a requeue.
#[test]
fn the_sbatch_script_stops_its_job_with_a_checkpoint_and_requeues_it() {
    use std::os::unix::process::CommandExt;
    let dir = tempfile::tempdir().unwrap();
    let manifest = manifest(dir.path(), 400);
    let batch = dir.path().join("batch");
    succeeds(&["batch", "plan", s(&manifest), "--out", s(&batch)]);
    succeeds(&["batch", "slurm", s(&batch), "--gpus", "0"]);
    let ids: Vec<String> = (0..2)
        .map(|i| jobs(&batch)["jobs"][i]["id"].as_str().unwrap().to_string())
        .collect();
    let tools = dir.path().join("tools");
    std::fs::create_dir_all(&tools).unwrap();
    let calls = dir.path().join("scontrol.calls");
    let scontrol = tools.join("scontrol");
    std::fs::write(
        &scontrol,
        format!("#!/bin/sh\necho \"$@\" >> '{}'\n", calls.display()),
    )
    .unwrap();
    Command::new("chmod")
        .arg("+x")
        .arg(&scontrol)
        .status()
        .unwrap();
    let path = format!("{}:{}", tools.display(), std::env::var("PATH").unwrap());
    for (task, signal) in [(0, "-USR1"), (1, "-TERM")] {
        let mut script = Command::new("bash");
        script
            .arg(batch.join("batch.sbatch"))
            .env("PATH", &path)
            .env("SLURM_ARRAY_JOB_ID", "7")
            .env("SLURM_ARRAY_TASK_ID", task.to_string())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .process_group(0);
        let mut child = script.spawn().unwrap();
        let checkpoint = batch.join(&ids[task]).join("checkpoint/state.json");
        while !checkpoint.exists() {
            assert!(
                child.try_wait().unwrap().is_none(),
                "task {task} ended early"
            );
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        // USR1 to the script alone; TERM to the whole task, as a cancel sends it.
        let target = if signal == "-USR1" {
            child.id().to_string()
        } else {
            format!("-{}", child.id())
        };
        let sent = Command::new("kill")
            .args([signal, "--", &target])
            .status()
            .unwrap();
        assert!(sent.success());
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(75), "task {task} ({signal})");
        let state =
            std::fs::read_to_string(batch.join("state").join(format!("{}.json", ids[task])))
                .unwrap();
        assert!(
            state.contains("\"exit_code\": 75") && state.contains("interrupted"),
            "{state}"
        );
    }
    let calls = std::fs::read_to_string(&calls).unwrap();
    assert_eq!(calls, "requeue 7_0\nrequeue 7_1\n");
}

#[test]
fn a_job_whose_scoring_failed_is_scored_again_without_stylizing_again() {
    // No checkpoint to tell that the stylization finished (checkpoint_every 0), and CLIP weights
    // for the scores that are found but do not load: the job stylizes, fails at scoring, and,
    // the weights mended, only scores when run again.
    let dir = tempfile::tempdir().unwrap();
    let path = manifest(dir.path(), 4);
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    m["set"]["checkpoint_every"] = 0.into();
    let good = PathBuf::from(m["eval"]["clip_weights"].as_str().unwrap());
    let weights = dir.path().join("eval_clip.safetensors");
    std::fs::write(&weights, b"not safetensors").unwrap();
    m["eval"]["clip_weights"] = s(&weights).into();
    std::fs::write(&path, m.to_string()).unwrap();
    let batch = dir.path().join("batch");
    succeeds(&["batch", "plan", s(&path), "--out", s(&batch)]);
    let id = jobs(&batch)["jobs"][0]["id"].as_str().unwrap().to_string();

    let out = run(&["batch", "run", s(&batch), "--index", "0", "--quiet"]);
    assert_eq!(out.status.code(), Some(65), "{out:?}");
    let model = batch.join(&id).join("model.ply");
    let modified = std::fs::metadata(&model).unwrap().modified().unwrap();
    assert!(!batch.join(&id).join("metrics.json").exists());
    let report = succeeds(&["batch", "status", s(&batch)]);
    assert!(report.contains("1 failed"), "{report}");

    std::fs::copy(&good, &weights).unwrap();
    let line = succeeds(&["batch", "run", s(&batch), "--index", "0", "--quiet"]);
    assert!(line.contains("stylized; scoring"), "{line}");
    assert!(batch.join(&id).join("metrics.json").is_file());
    assert_eq!(
        std::fs::metadata(&model).unwrap().modified().unwrap(),
        modified,
        "not stylized again"
    );
    let report = succeeds(&["batch", "status", s(&batch)]);
    assert!(report.contains("4 jobs: 1 done"), "{report}");

    // CLIP files that do not exist at all fail the job before it stylizes.
    std::fs::remove_file(&weights).unwrap();
    let out = run(&["batch", "run", s(&batch), "--index", "1", "--quiet"]);
    assert_eq!(out.status.code(), Some(65));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("eval.clip_weights"), "{stderr}");
    let second = jobs(&batch)["jobs"][1]["id"].as_str().unwrap().to_string();
    assert!(!batch.join(&second).join("model.ply").exists());
}
