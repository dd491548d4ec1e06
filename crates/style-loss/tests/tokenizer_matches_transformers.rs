//! Token ids against `transformers.CLIPTokenizer` built from CLIP's real BPE vocabulary (the
//! committed tokenizer.json keeps only the merges the reference prompts use).

mod common;

use common::{fixture, load_json};
use style_loss::templates::{format_templates, IMAGENET_TEMPLATES};
use style_loss::tokenizer::{ClipTokenizer, CONTEXT_LENGTH};

#[test]
fn ids_match_for_reference_prompts() {
    let tokenizer = ClipTokenizer::from_file(&fixture("tokenizer/tokenizer.json")).unwrap();
    let cases = load_json("tokenizer_reference.json");
    let cases = cases.as_array().unwrap();
    assert!(cases.len() >= 8);
    for case in cases {
        let prompt = case["prompt"].as_str().unwrap();
        let expected: Vec<u32> = serde_json::from_value(case["ids"].clone()).unwrap();
        let ids = tokenizer.encode(prompt).unwrap();
        assert_eq!(ids.len(), CONTEXT_LENGTH, "{prompt:?}");
        assert_eq!(ids, expected, "{prompt:?}");
    }
}

#[test]
fn paper_prompts_are_framed_and_long_prompts_truncated() {
    let tokenizer = ClipTokenizer::from_file(&fixture("tokenizer/tokenizer.json")).unwrap();
    let end = tokenizer.end_token_id();
    assert_eq!(end, 49407);
    let ids = tokenizer.encode("a Photo").unwrap();
    assert_eq!(&ids[..4], &[49406, 320, 1125, 49407]);
    assert!(ids[4..].iter().all(|&id| id == end));
    let long = tokenizer.encode(&["fire"; 90].join(" ")).unwrap();
    assert_eq!(long.len(), CONTEXT_LENGTH);
    assert_eq!(long[0], 49406);
    assert_eq!(long[CONTEXT_LENGTH - 1], end);
    assert!(long[1..CONTEXT_LENGTH - 1].iter().all(|&id| id != end));
}

#[test]
fn templates_format_the_prompt() {
    assert_eq!(IMAGENET_TEMPLATES.len(), 79);
    let texts = format_templates("fire");
    assert_eq!(texts.len(), 79);
    assert_eq!(texts[0], "a bad photo of a fire.");
    assert_eq!(texts[78], "a tattoo of the fire.");
    assert!(texts
        .iter()
        .all(|t| t.contains("fire") && !t.contains("{}")));
}

#[test]
fn missing_tokenizer_file_names_the_path() {
    let err = ClipTokenizer::from_file(&fixture("no_such_tokenizer.json"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("no_such_tokenizer.json"), "{err}");
}
