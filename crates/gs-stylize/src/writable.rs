//! Checks, before any work, that the outputs of a command can be written: an output folder
//! is a folder (or can be made) that this process can write in, an output file is not a
//! folder and its folder exists and can be written in. Every binary calls them first, so an
//! output that cannot be written costs no computation, and the error names the path and what
//! is wrong with it instead of a bare operating-system message.
//!
//! Writing in a folder is tried, not guessed from permission bits: an empty file with a
//! hidden name is created in it and removed again.

use std::io::ErrorKind;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// An output that cannot be written.
#[derive(Debug, thiserror::Error)]
#[error(
    "output {} {}: {problem}{}",
    if *.folder { "folder" } else { "file" },
    path.display(),
    source.as_ref().map_or(String::new(), |e| format!(" ({e})"))
)]
pub struct OutputError {
    /// Whether the output is a folder (else a file).
    pub folder: bool,
    /// The output as given.
    pub path: PathBuf,
    /// What is wrong with it.
    pub problem: String,
    /// The operating system's error behind it, when there is one.
    pub source: Option<std::io::Error>,
}

/// What is wrong with an output: a description, and the operating system's error behind it.
type Problem = (String, Option<std::io::Error>);

/// A problem without an operating-system error.
fn plain(problem: impl Into<String>) -> Problem {
    (problem.into(), None)
}

/// Checks that `dir` can be the output folder: an existing folder this process can write in,
/// or a path that does not exist yet whose nearest existing ancestor is such a folder (the
/// run creates the rest). Nothing is created.
pub fn check_output_folder(dir: &Path) -> Result<(), OutputError> {
    let bad = |(problem, source): Problem| OutputError {
        folder: true,
        path: dir.to_path_buf(),
        problem,
        source,
    };
    if dir.as_os_str().is_empty() {
        return Err(bad(plain("the path is empty")));
    }
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => try_write_in(dir).map_err(bad),
        Ok(_) => Err(bad(plain(
            "it is a file; the output must be a folder (name a new or existing folder)",
        ))),
        Err(e) if missing(&e) => {
            let (ancestor, is_dir) = nearest_existing(dir).map_err(bad)?;
            if !is_dir {
                return Err(bad(plain(format!(
                    "{} is a file, so no folder can be made in it",
                    ancestor.display()
                ))));
            }
            try_write_in(&ancestor)
                .map_err(|(why, e)| bad((format!("it cannot be created: {why}"), e)))
        }
        Err(e) => Err(bad(("it cannot be read".into(), Some(e)))),
    }
}

/// Checks that `file` can be written: it is not a folder, and its folder exists and this
/// process can write in it (files are written under a temporary name and renamed, so that is
/// what writing needs). Nothing is created.
pub fn check_output_file(file: &Path) -> Result<(), OutputError> {
    let bad = |(problem, source): Problem| OutputError {
        folder: false,
        path: file.to_path_buf(),
        problem,
        source,
    };
    if file.as_os_str().is_empty() {
        return Err(bad(plain("the path is empty")));
    }
    if file.is_dir() {
        return Err(bad(plain("it is a folder; the output must be a file name")));
    }
    let parent = folder_of(file);
    match std::fs::metadata(&parent) {
        Ok(m) if m.is_dir() => try_write_in(&parent).map_err(bad),
        Ok(_) => Err(bad(plain(format!(
            "{} is a file, not a folder",
            parent.display()
        )))),
        Err(e) if missing(&e) => match nearest_existing(&parent).map_err(bad)? {
            (ancestor, false) => Err(bad(plain(format!(
                "{} is a file, not a folder",
                ancestor.display()
            )))),
            (_, true) => Err(bad(plain(format!(
                "the folder {} does not exist",
                parent.display()
            )))),
        },
        Err(e) => Err(bad((
            format!("{} cannot be read", parent.display()),
            Some(e),
        ))),
    }
}

/// Whether `e` says that a path is not there (also when a component of it is a file).
fn missing(e: &std::io::Error) -> bool {
    matches!(e.kind(), ErrorKind::NotFound | ErrorKind::NotADirectory)
}

/// The folder `path` is in (`.` for a bare name).
fn folder_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// The nearest ancestor of `path` that exists, and whether it is a folder.
fn nearest_existing(path: &Path) -> Result<(PathBuf, bool), Problem> {
    for ancestor in path.ancestors().skip(1) {
        let ancestor = if ancestor.as_os_str().is_empty() {
            Path::new(".")
        } else {
            ancestor
        };
        match std::fs::metadata(ancestor) {
            Ok(m) => return Ok((ancestor.to_path_buf(), m.is_dir())),
            Err(e) if missing(&e) => continue,
            Err(e) => return Err((format!("{} cannot be read", ancestor.display()), Some(e))),
        }
    }
    Err(plain("no part of the path exists"))
}

/// Creates and removes an empty file in `dir`; the error says that `dir` cannot be written in.
fn try_write_in(dir: &Path) -> Result<(), Problem> {
    static COUNTER: AtomicUsize = AtomicUsize::new(0);
    let probe = dir.join(format!(
        ".clipgaussian-write-check-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .map_err(|e| (format!("cannot write in {}", dir.display()), Some(e)))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folders_and_files_that_cannot_be_outputs_are_named_with_the_reason() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("notes.txt");
        std::fs::write(&file, "x").unwrap();
        check_output_folder(dir.path()).unwrap();
        check_output_folder(&dir.path().join("new/deeper")).unwrap();
        check_output_file(&dir.path().join("out.json")).unwrap();
        check_output_file(&file).unwrap();

        let e = check_output_folder(&file).unwrap_err().to_string();
        assert!(
            e.contains("notes.txt: it is a file") && e.contains("must be a folder"),
            "{e}"
        );
        let e = check_output_folder(&file.join("sub/deeper"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("notes.txt is a file, so no folder"), "{e}");
        let e = check_output_file(dir.path()).unwrap_err().to_string();
        assert!(e.contains("it is a folder"), "{e}");
        let e = check_output_file(&file.join("m.json"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("notes.txt is a file, not a folder"), "{e}");
        let e = check_output_file(&dir.path().join("none/m.json"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("the folder") && e.contains("does not exist"),
            "{e}"
        );
        assert!(check_output_file(Path::new("")).is_err());
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "the checks leave nothing behind");
    }
}
