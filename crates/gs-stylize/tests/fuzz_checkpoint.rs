//! The checkpoint reader (`--resume`) against mutations of each file of a saved checkpoint
//! (`params.bin`, `adam.bin`, `state.json`), through gs-core's fuzz harness: no panic, no
//! allocation over its bound, errors naming the file or the checkpoint folder.

#[path = "../../gs-core/tests/fuzz/mod.rs"]
mod fuzz;

use std::collections::BTreeMap;

use fuzz::{fuzz, Counting};
use gs_core::adam::{Adam, AdamHyper, GroupConfig, LrSchedule};
use gs_core::model::BaseModel;
use gs_core::GaussianSet;
use gs_stylize::checkpoint::{self, model_params, Checkpoint};
use gs_stylize::outputs::StepLosses;

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// The optimizer of `model`'s groups, as a run builds it before it restores a checkpoint.
fn optimizer(model: &GaussianSet) -> Adam {
    let groups = model
        .group_names()
        .into_iter()
        .map(|name| GroupConfig::new(name, LrSchedule::Constant(0.01)))
        .collect();
    Adam::new(groups, &model.group_lens(), AdamHyper::default())
}

#[test]
fn the_checkpoint_reader_survives_mutated_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    std::fs::create_dir_all(&out).unwrap();
    let model = GaussianSet::zeros(5, 1);
    let saved = Checkpoint {
        step: 3,
        params: model_params(&model),
        adam_state: optimizer(&model).save_state(),
        rng: style_loss::style_rng(7),
        config: serde_json::json!({"steps": 10, "style": {"lambda_patch": 90.0}}),
        losses: (1..=3)
            .map(|step| StepLosses {
                step,
                view: 0,
                total: 1.5,
                terms: BTreeMap::from([("patch".to_string(), 1.0), ("content".into(), 0.5)]),
            })
            .collect(),
    };
    checkpoint::save(&out, &saved).unwrap();
    assert_eq!(checkpoint::load(&out).unwrap().step, 3);
    let folder = checkpoint::checkpoint_dir(&out);
    for (file, seed) in [("params.bin", 31), ("adam.bin", 32), ("state.json", 33)] {
        let target = folder.join(file);
        let valid = std::fs::read(&target).unwrap();
        let refused = fuzz(file, &valid, seed, |mutated| {
            std::fs::copy(mutated, &target).unwrap();
            let loaded = checkpoint::load(&out).map_err(|e| e.to_string())?;
            // What a resumed run does next: the optimizer state into the model's groups.
            optimizer(&model)
                .restore_state(&loaded.adam_state)
                .map_err(|e| format!("{}: {e}", target.display()))
        });
        std::fs::write(&target, &valid).unwrap();
        assert!(refused > 0, "{file}: no mutation was refused");
    }
}
