//! Where model files come from: an explicit path, else an environment variable, else the
//! Hugging Face cache, else (cargo feature `download`) a download with `hf-hub`. When none
//! works, the error names the repository, the file and where to put it.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use crate::error::{Result, StyleLossError};

/// A file of a Hugging Face model repository and the environment variable that may override
/// its location.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HubFile {
    /// Repository id, e.g. `openai/clip-vit-base-patch32`.
    pub repo: &'static str,
    /// Revision to look up in the cache and to download.
    pub revision: &'static str,
    /// File name inside the repository.
    pub file: &'static str,
    /// Environment variable holding a path to the file.
    pub env_var: &'static str,
}

/// CLIP ViT-B/32 weights (training). The safetensors file lives on the `refs/pr/15` revision.
pub const CLIP_VIT_B_32_WEIGHTS: HubFile = HubFile {
    repo: "openai/clip-vit-base-patch32",
    revision: "refs/pr/15",
    file: "model.safetensors",
    env_var: "CLIPGAUSSIAN_CLIP_B32_WEIGHTS",
};

/// CLIP's tokenizer.json (the same vocabulary for ViT-B/32 and ViT-L/14).
pub const CLIP_TOKENIZER: HubFile = HubFile {
    repo: "openai/clip-vit-base-patch32",
    revision: "refs/pr/15",
    file: "tokenizer.json",
    env_var: "CLIPGAUSSIAN_CLIP_TOKENIZER",
};

/// CLIP ViT-L/14 weights (evaluation).
pub const CLIP_VIT_L_14_WEIGHTS: HubFile = HubFile {
    repo: "openai/clip-vit-large-patch14",
    revision: "main",
    file: "model.safetensors",
    env_var: "CLIPGAUSSIAN_CLIP_L14_WEIGHTS",
};

/// VGG-19 ImageNet weights in torchvision's layout (`features.N.*`).
pub const VGG19_WEIGHTS: HubFile = HubFile {
    repo: "timm/vgg19.tv_in1k",
    revision: "main",
    file: "model.safetensors",
    env_var: "CLIPGAUSSIAN_VGG19_WEIGHTS",
};

/// The Hugging Face hub cache directory: `$HF_HUB_CACHE`, `$HF_HOME/hub`,
/// `$XDG_CACHE_HOME/huggingface/hub` or `~/.cache/huggingface/hub`.
pub fn hugging_face_cache_dir(env: &dyn Fn(&str) -> Option<OsString>) -> Option<PathBuf> {
    if let Some(dir) = env("HF_HUB_CACHE") {
        return Some(PathBuf::from(dir));
    }
    if let Some(home) = env("HF_HOME") {
        return Some(PathBuf::from(home).join("hub"));
    }
    if let Some(xdg) = env("XDG_CACHE_HOME") {
        return Some(PathBuf::from(xdg).join("huggingface").join("hub"));
    }
    env("HOME").map(|home| {
        PathBuf::from(home)
            .join(".cache")
            .join("huggingface")
            .join("hub")
    })
}

impl HubFile {
    /// The file's folder in a hub cache: `models--{org}--{name}`.
    fn cache_folder(&self, cache: &Path) -> PathBuf {
        cache.join(format!("models--{}", self.repo.replace('/', "--")))
    }

    /// The file in a hub cache: the snapshot of `revision` (via `refs/`), else any snapshot
    /// that has it.
    pub fn find_in_cache(&self, cache: &Path) -> Option<PathBuf> {
        let folder = self.cache_folder(cache);
        if let Ok(commit) = std::fs::read_to_string(folder.join("refs").join(self.revision)) {
            let path = folder.join("snapshots").join(commit.trim()).join(self.file);
            if path.is_file() {
                return Some(path);
            }
        }
        let mut snapshots: Vec<PathBuf> = std::fs::read_dir(folder.join("snapshots"))
            .ok()?
            .filter_map(|entry| entry.ok().map(|e| e.path().join(self.file)))
            .filter(|path| path.is_file())
            .collect();
        snapshots.sort();
        snapshots.into_iter().next()
    }

    /// Resolves the file with the process environment: [`Self::resolve_local_with`], then a
    /// download into the hub cache when the `download` feature is on (never for a missing
    /// explicit path).
    pub fn resolve(&self, explicit: Option<&Path>) -> Result<PathBuf> {
        let env = |name: &str| std::env::var_os(name);
        match self.search_local(explicit, &env) {
            Ok(path) => Ok(path),
            Err(tried) if explicit.is_some() => Err(self.not_found(tried)),
            Err(tried) => self.download(hugging_face_cache_dir(&env).as_deref(), tried),
        }
    }

    /// Resolves the file without any network access: `explicit` (which must exist if given),
    /// else the path in [`Self::env_var`], else the hub cache. `env` reads environment
    /// variables.
    pub fn resolve_local_with(
        &self,
        explicit: Option<&Path>,
        env: &dyn Fn(&str) -> Option<OsString>,
    ) -> Result<PathBuf> {
        self.search_local(explicit, env)
            .map_err(|tried| self.not_found(tried))
    }

    /// The local search; on failure, the places that were tried.
    fn search_local(
        &self,
        explicit: Option<&Path>,
        env: &dyn Fn(&str) -> Option<OsString>,
    ) -> std::result::Result<PathBuf, Vec<String>> {
        let mut tried = Vec::new();
        if let Some(path) = explicit {
            if path.is_file() {
                return Ok(path.to_path_buf());
            }
            tried.push(format!("the given path {} (no such file)", path.display()));
            return Err(tried);
        }
        match env(self.env_var) {
            Some(value) => {
                let path = PathBuf::from(value);
                if path.is_file() {
                    return Ok(path);
                }
                tried.push(format!(
                    "${}={} (no such file)",
                    self.env_var,
                    path.display()
                ));
            }
            None => tried.push(format!("${} (not set)", self.env_var)),
        }
        match hugging_face_cache_dir(env) {
            Some(cache) => {
                if let Some(path) = self.find_in_cache(&cache) {
                    return Ok(path);
                }
                tried.push(format!("the Hugging Face cache {}", cache.display()));
            }
            None => tried.push("the Hugging Face cache (no HOME)".into()),
        }
        Err(tried)
    }

    #[cfg(feature = "download")]
    fn download(&self, cache: Option<&Path>, mut tried: Vec<String>) -> Result<PathBuf> {
        let mut builder = hf_hub::api::sync::ApiBuilder::new();
        if let Some(cache) = cache {
            builder = builder.with_cache_dir(cache.to_path_buf());
        }
        let repo = hf_hub::Repo::with_revision(
            self.repo.to_string(),
            hf_hub::RepoType::Model,
            self.revision.to_string(),
        );
        match builder
            .build()
            .and_then(|api| api.repo(repo).get(self.file))
        {
            Ok(path) => Ok(path),
            Err(e) => {
                tried.push(format!("a download ({e})"));
                Err(self.not_found(tried))
            }
        }
    }

    #[cfg(not(feature = "download"))]
    fn download(&self, _cache: Option<&Path>, mut tried: Vec<String>) -> Result<PathBuf> {
        tried.push("no download (the `download` cargo feature is off)".into());
        Err(self.not_found(tried))
    }

    fn not_found(&self, tried: Vec<String>) -> StyleLossError {
        StyleLossError::WeightsNotFound {
            repo: self.repo.to_string(),
            revision: self.revision.to_string(),
            file: self.file.to_string(),
            env_var: self.env_var.to_string(),
            tried: tried.join("; "),
        }
    }
}
