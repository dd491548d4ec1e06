//! The evaluation metrics: hand-built embeddings with known answers, degenerate inputs, the
//! evaluation preprocess, and the whole pipeline on a tiny CLIP.

mod common;

use candle_core::{Device, Tensor};
use common::fixture;
use style_loss::clip::{ClipConfig, ClipModel};
use style_loss::metrics::{
    clip_cons, clip_f, clip_s, clip_sim, evaluate, evaluate_pairs, evaluation_preprocess,
    image_embeddings, ClipScores, StyleReference,
};
use style_loss::{ClipTokenizer, NamedTensors, DEFAULT_SOURCE_PROMPT};

fn t2(rows: &[[f32; 3]]) -> Tensor {
    let flat: Vec<f32> = rows.iter().flatten().copied().collect();
    Tensor::from_vec(flat, (rows.len(), 3), &Device::Cpu).unwrap()
}

fn t1(v: [f32; 3]) -> Tensor {
    Tensor::new(&v, &Device::Cpu).unwrap()
}

fn assert_near(got: f64, want: f64) {
    assert!((got - want).abs() < 1e-5, "{got} vs {want}");
}

const X: [f32; 3] = [1.0, 0.0, 0.0];
const Y: [f32; 3] = [0.0, 1.0, 0.0];
const Z: [f32; 3] = [0.0, 0.0, 1.0];

#[test]
fn clip_s_is_the_mean_cosine_with_the_style() {
    // cos 1 and cos 0: mean 0.5.
    assert_near(clip_s(&t2(&[X, Y]), &t1(X)).unwrap(), 50.0);
    // Unnormalized rows are normalized: cos of [1, 1, 0] with x is 1/sqrt 2.
    let r = t2(&[[2.0, 2.0, 0.0]]);
    assert_near(clip_s(&r, &t1(X)).unwrap(), 100.0 / 2f64.sqrt());
    assert_near(clip_s(&t2(&[[-1.0, 0.0, 0.0]]), &t1(X)).unwrap(), -100.0);
}

#[test]
fn clip_sim_compares_the_change_with_the_style_direction() {
    // style - neutral = x - y. Render 0 moved from y to x (parallel: 1), render 1 moved from z
    // to -z (orthogonal: 0), render 2 did not move (zero difference: 0).
    let r = t2(&[X, [0.0, 0.0, -1.0], Z]);
    let gt = t2(&[Y, Z, Z]);
    assert_near(clip_sim(&r, &gt, &t1(X), &t1(Y)).unwrap(), 100.0 / 3.0);
    // Moving against the direction gives -100.
    let sim = clip_sim(&t2(&[Y]), &t2(&[X]), &t1(X), &t1(Y)).unwrap();
    assert_near(sim, -100.0);
}

#[test]
fn clip_cons_compares_consecutive_changes() {
    // Steps of the renders: x->y, y->z; of the ground truths: x->y, z->y (= -(y->z)).
    let r = t2(&[X, Y, Z]);
    let gt = t2(&[X, Y, [0.0, 2.0, -1.0]]);
    // cos(y - x, y - x) = 1; cos(z - y, [0, 1, -1]) = -1.
    assert_near(clip_cons(&r, &gt).unwrap(), 0.0);
    assert_near(clip_cons(&r, &r).unwrap(), 100.0);
    // A render that does not change between views gives 0, not NaN.
    let still = t2(&[X, X, X]);
    assert_near(clip_cons(&still, &r).unwrap(), 0.0);
}

#[test]
fn clip_f_is_the_ratio_of_consecutive_similarities() {
    // Renders: cos(x, y) = 0, cos(y, y) = 1: mean 0.5. Ground truths all x: mean 1.
    let r = t2(&[X, Y, Y]);
    let gt = t2(&[X, X, X]);
    assert_near(clip_f(&r, &gt).unwrap(), 50.0);
    assert_near(clip_f(&r, &r).unwrap(), 100.0);
    // Smoother renders than ground truths score above 100.
    assert_near(clip_f(&gt, &r).unwrap(), 200.0);
}

#[test]
fn scores_gather_the_four_metrics() {
    let r = t2(&[X, Y, Z]);
    let gt = t2(&[Y, Y, Y]);
    let scores = ClipScores::from_embeddings(&r, &gt, &t1(X), &t1(Z)).unwrap();
    assert_near(scores.s, clip_s(&r, &t1(X)).unwrap());
    assert_near(scores.sim, clip_sim(&r, &gt, &t1(X), &t1(Z)).unwrap());
    assert_near(scores.cons.unwrap(), clip_cons(&r, &gt).unwrap());
    assert_near(scores.f.unwrap(), clip_f(&r, &gt).unwrap());
    // One view: no consecutive pair, so CLIP-CONS and CLIP-F are absent.
    let one = ClipScores::from_embeddings(&t2(&[X]), &t2(&[Y]), &t1(X), &t1(Z)).unwrap();
    assert_near(one.s, 100.0);
    assert_eq!((one.cons, one.f), (None, None));
}

#[test]
fn degenerate_inputs_are_errors() {
    let one = t2(&[X]);
    for err in [
        clip_cons(&one, &one).unwrap_err(),
        clip_f(&one, &one).unwrap_err(),
    ] {
        assert!(err.to_string().contains("at least 2"), "{err}");
    }
    // Orthogonal consecutive ground truths: the CLIP-F denominator is zero.
    let err = clip_f(&t2(&[X, X]), &t2(&[X, Y])).unwrap_err().to_string();
    assert!(err.contains("CLIP-F") && err.contains("0"), "{err}");
    // Mismatched counts and widths name the numbers.
    let err = clip_sim(&t2(&[X, Y]), &one, &t1(X), &t1(Y))
        .unwrap_err()
        .to_string();
    assert!(err.contains("1 ground truths for 2 renders"), "{err}");
    let wide = Tensor::zeros((4,), candle_core::DType::F32, &Device::Cpu).unwrap();
    let err = clip_s(&one, &wide).unwrap_err().to_string();
    assert!(err.contains("dimension 4") && err.contains("3"), "{err}");
    // Empty lists and NaN embeddings.
    let empty = Tensor::zeros((0, 3), candle_core::DType::F32, &Device::Cpu).unwrap();
    assert!(clip_s(&empty, &t1(X)).is_err());
    let nan = t2(&[[f32::NAN, 0.0, 0.0]]);
    let err = clip_s(&nan, &t1(X)).unwrap_err().to_string();
    assert!(err.contains("non-finite"), "{err}");
}

#[test]
fn preprocess_resizes_the_short_side_and_crops_the_centre() {
    // 2 x 6 image whose columns are 8-bit values: short side to 4 gives 4 x 12 (Pillow's
    // bicubic), the centre crop keeps columns 4..8 of the resized image.
    let column_bytes: Vec<u8> = (0..3 * 2 * 6)
        .map(|i| (i % 6 * 40 + i / 12) as u8)
        .collect();
    let columns: Vec<f32> = column_bytes.iter().map(|&b| f32::from(b) / 255.0).collect();
    let image = Tensor::from_vec(columns, (3, 2, 6), &Device::Cpu).unwrap();
    let pixels = evaluation_preprocess(&image, 4).unwrap();
    assert_eq!(pixels.dims(), &[1, 3, 4, 4]);
    let full =
        style_loss::pil_resize::pil_bicubic_resize(&column_bytes, 3, (2, 6), (4, 12)).unwrap();
    let mean = style_loss::clip::CLIP_MEAN;
    let std = style_loss::clip::CLIP_STD;
    let got = pixels.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    for (k, g) in got.iter().enumerate() {
        let (c, row, col) = (k / 16, k / 4 % 4, k % 4);
        let byte = full[c * 48 + row * 12 + 4 + col];
        let want = (f32::from(byte) / 255.0 - mean[c]) / std[c];
        assert!((g - want).abs() < 1e-5, "{k}: {g} vs {want}");
    }
    // Tall images crop rows; odd margins round half to even (margin 1 -> offset round(0.5) = 0).
    // The 5 x 4 image needs no resize; rows hold their index, so the crop starts at row 0.
    let rows: Vec<f32> = (0..4 * 5 * 4)
        .map(|i| ((i / 4) % 5) as f32 / 255.0)
        .collect();
    let tall = Tensor::from_vec(rows, (1, 4, 5, 4), &Device::Cpu).unwrap();
    let pixels = evaluation_preprocess(&tall, 4).unwrap();
    assert_eq!(pixels.dims(), &[1, 3, 4, 4]);
    let first_column: Vec<f64> = pixels
        .get(0)
        .unwrap()
        .get(0)
        .unwrap()
        .to_vec2::<f32>()
        .unwrap()
        .iter()
        .map(|row| (row[0] * std[0] + mean[0]) as f64 * 255.0)
        .collect();
    for (k, v) in first_column.iter().enumerate() {
        assert!((v - k as f64).abs() < 1e-3, "{first_column:?}");
    }
    // Values are taken to 8 bits as torchvision's `save_image` does (clamped, 255 x + 0.5
    // truncated); NaN is an error, an empty image too.
    let odd = Tensor::from_vec(
        vec![-0.5f32, 1.5, 0.5 / 255.0, 0.49 / 255.0],
        (1, 1, 2, 2),
        &Device::Cpu,
    )
    .unwrap()
    .broadcast_as((1, 3, 2, 2))
    .unwrap()
    .contiguous()
    .unwrap();
    let bytes: Vec<f32> = evaluation_preprocess(&odd, 2)
        .unwrap()
        .get(0)
        .unwrap()
        .get(0)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap()
        .iter()
        .map(|v| ((v * std[0] + mean[0]) * 255.0).round())
        .collect();
    assert_eq!(bytes, [0.0, 255.0, 1.0, 0.0]);
    let nan = Tensor::full(f32::NAN, (3, 4, 4), &Device::Cpu).unwrap();
    let err = evaluation_preprocess(&nan, 4).unwrap_err().to_string();
    assert!(err.contains("NaN"), "{err}");
    let flat = Tensor::ones((3, 0, 4), candle_core::DType::F32, &Device::Cpu).unwrap();
    assert!(evaluation_preprocess(&flat, 4).is_err());
}

/// A tiny CLIP over the real vocabulary size (random weights), so that the tokenizer's ids of
/// the reference prompts ("fire", "a Photo") reach the text tower.
fn tiny_clip_with_vocabulary() -> ClipModel {
    let mut config = ClipConfig::from_json_file(&fixture("tiny_clip/config.json")).unwrap();
    config.text.vocab_size = 49408;
    config.text.eos_token_id = 49407;
    ClipModel::from_tensors(&config, &NamedTensors::random(&Device::Cpu), &Device::Cpu).unwrap()
}

fn gradient_image(h: usize, w: usize, phase: f32) -> Tensor {
    let values: Vec<f32> = (0..3 * h * w)
        .map(|i| 0.5 + 0.5 * ((i as f32) * 0.37 + phase).sin())
        .collect();
    Tensor::from_vec(values, (3, h, w), &Device::Cpu).unwrap()
}

#[test]
fn whole_evaluation_runs_on_a_tiny_clip() {
    let clip = tiny_clip_with_vocabulary();
    let tokenizer = ClipTokenizer::from_file(&fixture("tokenizer/tokenizer.json")).unwrap();
    let style = gradient_image(80, 96, 0.0);
    let renders: Vec<Tensor> = (0..4)
        .map(|k| gradient_image(70, 90 + k, k as f32))
        .collect();
    let truths: Vec<Tensor> = (0..4)
        .map(|k| gradient_image(90 + k, 70, 2.0 * k as f32))
        .collect();

    let text = evaluate(
        &clip,
        &tokenizer,
        StyleReference::Prompt("fire"),
        DEFAULT_SOURCE_PROMPT,
        &renders,
        &truths,
    )
    .unwrap();
    for v in [text.s, text.sim, text.cons.unwrap(), text.f.unwrap()] {
        assert!(v.is_finite() && v.abs() <= 1e4, "{text:?}");
    }

    // Identical renders and ground truths: CLIP-F is 100, CLIP-CONS 100, CLIP-SIM 0.
    let same = evaluate(
        &clip,
        &tokenizer,
        StyleReference::Image(&style),
        DEFAULT_SOURCE_PROMPT,
        &renders,
        &renders,
    )
    .unwrap();
    assert!((same.f.unwrap() - 100.0).abs() < 1e-6, "{same:?}");
    assert!((same.cons.unwrap() - 100.0).abs() < 1e-6, "{same:?}");
    assert_eq!(same.sim, 0.0);

    // The style image rendered as every view: CLIP-S is 100.
    let styled = vec![style.clone(), style.unsqueeze(0).unwrap()];
    let own = evaluate(
        &clip,
        &tokenizer,
        StyleReference::Image(&style),
        DEFAULT_SOURCE_PROMPT,
        &styled,
        &truths[..2],
    )
    .unwrap();
    assert!((own.s - 100.0).abs() < 1e-4, "{own:?}");

    let embeddings = image_embeddings(&clip, &renders).unwrap();
    assert_eq!(embeddings.dims(), &[4, 16]);
    let err = evaluate(
        &clip,
        &tokenizer,
        StyleReference::Prompt("fire"),
        DEFAULT_SOURCE_PROMPT,
        &renders,
        &truths[..3],
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("3 ground truths for 4 renders"), "{err}");
}

#[test]
fn embeddings_do_not_depend_on_batching() {
    // 17 images span two batches of the vision tower; each row equals the image embedded alone.
    let clip = tiny_clip_with_vocabulary();
    let images: Vec<Tensor> = (0..17)
        .map(|k| gradient_image(64 + k, 72, k as f32))
        .collect();
    let all = image_embeddings(&clip, &images).unwrap();
    assert_eq!(all.dims(), &[17, 16]);
    for k in [0, 15, 16] {
        let alone = image_embeddings(&clip, &images[k..k + 1]).unwrap();
        let diff = (all.get(k).unwrap() - alone.get(0).unwrap())
            .unwrap()
            .abs()
            .unwrap()
            .max(0)
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert!(diff < 1e-5, "row {k}: {diff}");
    }
    assert!(image_embeddings(&clip, &[]).is_err());
}

#[test]
fn pairs_given_one_by_one_score_as_the_whole_lists() {
    // 19 pairs: two batches of the vision tower, the second short. The pairs are asked for in
    // order, and the scores are those of the embeddings of the whole lists.
    let clip = tiny_clip_with_vocabulary();
    let tokenizer = ClipTokenizer::from_file(&fixture("tokenizer/tokenizer.json")).unwrap();
    let renders: Vec<Tensor> = (0..19)
        .map(|k| gradient_image(60 + k, 70, k as f32))
        .collect();
    let truths: Vec<Tensor> = (0..19)
        .map(|k| gradient_image(70, 60 + k, 0.5 * k as f32))
        .collect();
    // The evaluation of the pairs, failing at pair `fail` when given; the pairs asked for.
    let stream = |fail: Option<usize>| {
        let mut asked = Vec::new();
        let scores = evaluate_pairs(
            &clip,
            &tokenizer,
            StyleReference::Prompt("fire"),
            DEFAULT_SOURCE_PROMPT,
            renders.len(),
            |i| {
                asked.push(i);
                if Some(i) == fail {
                    return Err(Box::new(style_loss::StyleLossError::Input {
                        name: "pair".into(),
                        reason: "unreadable".into(),
                    }));
                }
                Ok((renders[i].clone(), truths[i].clone()))
            },
        );
        (scores, asked)
    };
    let (streamed, asked) = stream(None);
    let streamed = streamed.unwrap();
    assert_eq!(asked, (0..19).collect::<Vec<_>>());
    let style = style_loss::style_direction::prompt_embedding(&clip, &tokenizer, "fire").unwrap();
    let neutral =
        style_loss::style_direction::prompt_embedding(&clip, &tokenizer, DEFAULT_SOURCE_PROMPT)
            .unwrap();
    let whole = ClipScores::from_embeddings(
        &image_embeddings(&clip, &renders).unwrap(),
        &image_embeddings(&clip, &truths).unwrap(),
        &style,
        &neutral,
    )
    .unwrap();
    assert_eq!(streamed, whole);
    // An error of a pair is the evaluation's.
    let (failed, _) = stream(Some(17));
    assert!(failed.unwrap_err().to_string().contains("unreadable"));
}
