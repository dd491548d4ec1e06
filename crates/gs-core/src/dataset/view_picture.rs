//! One view's ground truth and the camera it is trained with, whatever the layout: the picture
//! from the full-size folder or a pre-downscaled one, undistorted when its lens is, resized to
//! the training size.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::model::View;
use crate::{Camera, GsError, Image};

use super::images::{self, Composite};
use super::undistort::{LensDistortion, Undistortion};
use super::{
    training_camera, BackgroundMask, DatasetError, DatasetView, ImageCounter, LoadOptions,
    LoadedFrame,
};

/// One view as its dataset's files give it, before its picture is read.
pub(crate) struct ViewSpec {
    /// Where its picture is.
    pub picture: PictureFile,
    /// The camera of the full-size stored picture (distorted when `lens` is given).
    pub full: Camera,
    /// The lens to undo, if any.
    pub lens: Option<LensDistortion>,
    /// The camera model's name, for the undistortion's report.
    pub model: String,
    /// The view's time.
    pub time: f64,
    /// The file and frame or image that describe the view, for errors.
    pub context: String,
}

/// Every view of `specs` with its picture, loaded in parallel and composited as `composite`
/// says; the error is the first failing view's, in order.
pub(crate) fn load_all(
    specs: &[ViewSpec],
    options: &LoadOptions,
    composite: Composite,
) -> Result<Vec<LoadedFrame>, DatasetError> {
    let counter = ImageCounter::new(options, specs.len());
    specs
        .par_iter()
        .map(|spec| {
            let context = || spec.context.clone();
            let (camera, image, mask, undistortion) = load(
                &spec.picture,
                &spec.full,
                spec.lens,
                options,
                composite,
                &context,
            )?;
            counter.one_done();
            Ok(LoadedFrame {
                view: View {
                    camera,
                    time: spec.time,
                },
                image,
                mask,
                path: spec.picture.path.clone(),
                undistorted: undistortion.map(|u| u.report(&spec.model)),
            })
        })
        // Gathered in order first, so the error reported is that of the first failing view.
        .collect::<Vec<Result<_, DatasetError>>>()
        .into_iter()
        .collect()
}

/// Every view of `specs` as [`load_all`] would give it, without decoding a picture (see
/// [`camera`]).
pub(crate) fn views(
    specs: &[ViewSpec],
    options: &LoadOptions,
) -> Result<Vec<DatasetView>, DatasetError> {
    specs
        .iter()
        .map(|spec| {
            let context = || spec.context.clone();
            let found = camera(&spec.picture, &spec.full, spec.lens, options, &context)?;
            Ok(DatasetView {
                view: View {
                    camera: found.camera,
                    time: spec.time,
                },
                picture: spec.picture.path.clone(),
            })
        })
        .collect()
}

/// Where a view's picture is.
pub(crate) struct PictureFile {
    /// The file.
    pub path: PathBuf,
    /// Whether it is in a pre-downscaled folder (`images_<f>/`): its size is then within one
    /// pixel of the downscaled camera's per axis (tools round differently), its intrinsics are
    /// scaled to its exact size, and it is not resized.
    pub prescaled: bool,
}

/// The folder `root/images_<f>` when downscaling by `f > 1` and it exists: pictures downscaled
/// beforehand (COLMAP's and nerfstudio's `images_2/4/8`), read by file name.
pub(crate) fn prescaled_folder(root: &Path, downscale: u32) -> Option<PathBuf> {
    let folder = root.join(format!("images_{downscale}"));
    (downscale > 1 && folder.is_dir()).then_some(folder)
}

/// A view's camera as trained, with what its picture needs to be loaded.
pub(crate) struct ViewCamera {
    /// The camera of the loaded picture (undistorted, resized to the training size).
    pub camera: Camera,
    /// The camera of the stored picture (distorted when it has a lens).
    pub stored: Camera,
    /// The undistortion of the stored picture, when it has a lens.
    pub undistortion: Option<Undistortion>,
}

/// The camera [`load`] would give the view of `picture`, without decoding it: only a
/// pre-downscaled picture's header, or a distorted one's, is read (for its size).
pub(crate) fn camera(
    picture: &PictureFile,
    full: &Camera,
    lens: Option<LensDistortion>,
    options: &LoadOptions,
    context: &dyn Fn() -> String,
) -> Result<ViewCamera, DatasetError> {
    let camera_error = |source| DatasetError::Camera {
        context: context(),
        source,
    };
    let lens = lens.filter(|lens| !lens.is_none());
    super::undistort::check_intrinsics(
        [full.fx, full.fy, full.cx, full.cy],
        full.width,
        full.height,
    )
    .map_err(|why| camera_error(GsError::InvalidCamera(why)))?;
    let stored = if picture.prescaled {
        let scaled = training_camera(full, options).map_err(camera_error)?;
        let found = images::dimensions(&picture.path).map_err(|e| of_view(e, context))?;
        if found.0.abs_diff(scaled.width) > 1 || found.1.abs_diff(scaled.height) > 1 {
            return Err(DatasetError::ImageSize {
                path: picture.path.clone(),
                expected: (scaled.width, scaled.height),
                found,
                says: context(),
            });
        }
        full.resized(found.0, found.1).map_err(camera_error)?
    } else {
        if lens.is_some() {
            // Checked before the undistortion's map (8 bytes a pixel) is built for it.
            let found = images::dimensions(&picture.path).map_err(|e| of_view(e, context))?;
            if found != (full.width, full.height) {
                return Err(DatasetError::ImageSize {
                    path: picture.path.clone(),
                    expected: (full.width, full.height),
                    found,
                    says: context(),
                });
            }
        }
        full.clone()
    };
    let undistortion = lens
        .map(|lens| {
            Undistortion::new(
                [stored.fx, stored.fy, stored.cx, stored.cy],
                lens,
                stored.width,
                stored.height,
            )
            .map_err(|why| camera_error(GsError::InvalidCamera(why)))
        })
        .transpose()?;
    let pinhole = match &undistortion {
        Some(u) => Camera::new(
            stored.rotation,
            stored.translation,
            u.intrinsics,
            u.width,
            u.height,
        )
        .map_err(camera_error)?,
        None => stored.clone(),
    };
    let camera = if picture.prescaled {
        pinhole
    } else {
        training_camera(&pinhole, options).map_err(camera_error)?
    };
    Ok(ViewCamera {
        camera,
        stored,
        undistortion,
    })
}

/// A view's picture: `picture`, stored at the size of `full` (or pre-downscaled), its lens
/// `lens` undone first when given (`full`'s intrinsics are then the distorted camera's), then
/// resized to the training size of `options`. Returns the camera of the loaded picture, the
/// picture composited as `composite` says, its background mask, and the undistortion used.
/// `context` names the frame or image in errors about its camera.
pub(crate) fn load(
    picture: &PictureFile,
    full: &Camera,
    lens: Option<LensDistortion>,
    options: &LoadOptions,
    composite: Composite,
    context: &dyn Fn() -> String,
) -> Result<(Camera, Image, Option<BackgroundMask>, Option<Undistortion>), DatasetError> {
    let ViewCamera {
        camera,
        stored,
        undistortion,
    } = self::camera(picture, full, lens, options, context)?;
    let (image, mask) = images::load(
        &picture.path,
        (stored.width, stored.height),
        Some((camera.width, camera.height)),
        options.background.rgb(),
        composite,
        undistortion.as_ref(),
    )
    .map_err(|e| of_view(e, context))?;
    Ok((camera, image, mask, undistortion))
}

/// `e` with a missing picture, or one of another size, said to be the picture of the view
/// `context` names (the file and frame or image that refer to it).
fn of_view(e: DatasetError, context: &dyn Fn() -> String) -> DatasetError {
    match e {
        DatasetError::Missing { path, .. } => DatasetError::Missing {
            path,
            what: format!("the picture of {}", context()),
        },
        DatasetError::ImageSize {
            path,
            expected,
            found,
            ..
        } => DatasetError::ImageSize {
            path,
            expected,
            found,
            says: context(),
        },
        e => e,
    }
}
