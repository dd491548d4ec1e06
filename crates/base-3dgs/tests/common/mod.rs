//! A temporary folder for the integration tests, and checks they share.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// A fresh folder under the system's temporary folder, removed when dropped.
pub struct TempDir(PathBuf);

impl TempDir {
    /// A new empty folder whose name contains `name`, the process id and a counter.
    pub fn new(name: &str) -> Self {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("base-3dgs-{name}-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("create temporary folder");
        Self(dir)
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// `views` (read without decoding a picture) are the loaded dataset's views and pictures.
#[allow(dead_code)] // Not every test crate including this module checks views.
pub fn same_views(data: &base_3dgs::dataset::Dataset, views: &[base_3dgs::dataset::DatasetView]) {
    let cameras: Vec<_> = views.iter().map(|v| v.view.clone()).collect();
    let pictures: Vec<_> = views.iter().map(|v| v.picture.clone()).collect();
    assert_eq!(cameras, data.views);
    assert_eq!(pictures, data.image_paths);
}
