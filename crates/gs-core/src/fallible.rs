//! Allocations sized by an input file, made fallibly: a file that asks for more memory than
//! the machine can give is refused with an error naming what was being read, instead of
//! aborting the process. (Counts are checked against the file's length first; this is what
//! is left when a valid file is simply too large for this machine.)

/// An allocation the machine refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "{what} need {}, which this machine could not reserve (too large for its memory)",
    size(*bytes)
)]
pub struct OutOfMemory {
    /// The bytes asked for.
    pub bytes: usize,
    /// What they were for, e.g. `the Gaussians' arrays`.
    pub what: &'static str,
}

/// `1.2 GB`, or `340 MB` below a gigabyte.
fn size(bytes: usize) -> String {
    let bytes = bytes as f64;
    if bytes >= 1e9 {
        format!("{:.1} GB", bytes / 1e9)
    } else {
        format!("{:.1} MB", bytes / 1e6)
    }
}

/// An empty vector with room for `len` values, or the error when the machine refuses it.
pub fn with_capacity<T>(len: usize, what: &'static str) -> Result<Vec<T>, OutOfMemory> {
    let mut v = Vec::new();
    v.try_reserve_exact(len).map_err(|_| OutOfMemory {
        bytes: len.saturating_mul(std::mem::size_of::<T>()),
        what,
    })?;
    Ok(v)
}

/// `len` copies of `value`, or the error when the machine refuses the memory.
pub fn filled<T: Clone>(len: usize, value: T, what: &'static str) -> Result<Vec<T>, OutOfMemory> {
    let mut v = with_capacity(len, what)?;
    v.resize(len, value);
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_impossible_size_is_an_error_naming_what_it_was_for() {
        let e = filled(usize::MAX / 8, 0.0f64, "the test's values").unwrap_err();
        assert_eq!(e.what, "the test's values");
        assert!(e.to_string().contains("the test's values need"), "{e}");
        assert_eq!(filled(3, 7u8, "three").unwrap(), [7, 7, 7]);
        assert!(with_capacity::<u32>(5, "five").unwrap().capacity() >= 5);
    }
}
