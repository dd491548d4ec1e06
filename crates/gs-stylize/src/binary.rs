//! One skeleton for the four binaries: their subcommands in one order (`stylize`, the
//! modality's own ones such as `fit`, `render`, `interpolate`, `export`, `eval`, `selftest`),
//! the parsing of the command line and the dispatch, and the process's start and exit. A
//! binary is its modality's part only: an implementation of [`ModalityBinary`] (the flags of
//! its subcommands, whose doc comments are their help, and what each does) and
//! `fn main() -> ExitCode { gs_stylize::binary::main::<Its>() }`.

use std::error::Error;
use std::ffi::OsString;
use std::path::Path;
use std::process::ExitCode;

use clap::{Args, CommandFactory, FromArgMatches, Parser, Subcommand};
use gs_core::interpolate::interpolate_ply;
use gs_core::ply::{read_ply_with_format, write_ply, PlyFormat, PlyGaussians};

use crate::cli::{exit_code, InterpolateArgs, SelftestArgs};
use crate::model_kind::Binary;
use crate::selftest::ExtraCheck;

/// What a modality's binary adds to the skeleton. Each `Args` type's doc comment is its
/// subcommand's help (`--help` shows it whole, the list of subcommands its first sentence).
pub trait ModalityBinary {
    /// The binary: its name, and which model files it opens.
    const BINARY: Binary;
    /// What the binary does, the first line of its `--help`.
    const ABOUT: &'static str;
    /// The help of `interpolate`, whose flags are the same in every binary: a first sentence,
    /// then paragraphs, each on one line, separated by a blank line.
    const INTERPOLATE_HELP: &'static str;
    /// The longer help of `selftest` where the modality checks parts of its own
    /// ([`ModalityBinary::self_checks`]); the shared one otherwise.
    const SELFTEST_HELP: Option<&'static str> = None;

    /// The flags of `stylize`.
    type Stylize: Args;
    /// The modality's own subcommands, listed after `stylize` (its `fit`).
    type Own: Subcommand;
    /// The flags of `render`.
    type Render: Args;
    /// The flags of `export`.
    type Export: Args;
    /// The flags of `eval`.
    type Eval: Args;
    /// A model file as `interpolate` reads it (`--a`, `--b`), and `render` and `export`
    /// where they need nothing more: its Gaussians and what the file records beside them,
    /// which a blend keeps from the first.
    type Model;

    /// Reads a model file (or a model folder where the modality's format is one).
    fn read_model(path: &Path) -> Result<Self::Model, Box<dyn Error>>;
    /// Writes `model` where [`ModalityBinary::read_model`] reads it back.
    fn write_model(path: &Path, model: &Self::Model) -> Result<(), Box<dyn Error>>;
    /// `(1 - t) a + t b` parameter by parameter (opacities in logit space, scales in log
    /// space, quaternions normalized), with `a`'s record; or why the two do not blend.
    fn blend(a: &Self::Model, b: &Self::Model, t: f32) -> Result<Self::Model, String>;
    /// How many Gaussians `model` has.
    fn gaussian_count(model: &Self::Model) -> usize;

    /// Runs `stylize`.
    fn stylize(args: &Self::Stylize) -> Result<(), Box<dyn Error>>;
    /// Runs one of the modality's own subcommands.
    fn own(command: &Self::Own) -> Result<(), Box<dyn Error>>;
    /// Runs `render`.
    fn render(args: &Self::Render) -> Result<(), Box<dyn Error>>;
    /// Runs `export`.
    fn export(args: &Self::Export) -> Result<(), Box<dyn Error>>;
    /// Runs `eval`.
    fn eval(args: &Self::Eval) -> Result<(), Box<dyn Error>>;
    /// The modality's own parts of `selftest`, run after the shared ones (none by default).
    fn self_checks() -> Vec<ExtraCheck> {
        Vec::new()
    }
}

/// The command line of a modality's binary.
#[derive(Parser)]
#[command(version)]
struct Cli<M: ModalityBinary> {
    /// What to do.
    #[command(subcommand)]
    command: Command<M>,
}

/// The subcommands, in the order every binary lists them. Only `selftest` has its help here:
/// the others take theirs from their flags' doc comments (or, for `interpolate`, from
/// [`ModalityBinary::INTERPOLATE_HELP`]), which a doc comment on the variant would replace.
#[derive(Subcommand)]
enum Command<M: ModalityBinary> {
    Stylize(M::Stylize),
    // The modality's own subcommands (`fit`).
    #[command(flatten)]
    Own(M::Own),
    Render(M::Render),
    Interpolate(InterpolateArgs),
    Export(M::Export),
    Eval(M::Eval),
    /// Check the device: every part of a stylization on small seeded inputs against the cpu.
    ///
    /// Runs the render and its backward, Adam, each loss term and the loss gradient on
    /// the chosen device and compares each with the cpu f32 result (on the cpu, the loss with
    /// its generic composition, the one a GPU runs); prints a table (part, device, max error,
    /// tolerance, time) and exits with an error when a part differs.
    Selftest(SelftestArgs),
}

/// The help of a subcommand as clap's derive makes it from a doc comment: its first paragraph
/// without the full stop (`-h`, and the list of subcommands), and the whole text for `--help`
/// when there is more than one paragraph.
fn help_of(text: &'static str) -> (&'static str, Option<&'static str>) {
    match text.split_once("\n\n") {
        Some((first, _)) => (first.strip_suffix('.').unwrap_or(first), Some(text)),
        None => (text.strip_suffix('.').unwrap_or(text), None),
    }
}

/// Runs `interpolate`: checks its files before any work ([`InterpolateArgs::check`]), reads
/// the two models, writes their blend and says so.
fn interpolate<M: ModalityBinary>(args: &InterpolateArgs) -> Result<(), Box<dyn Error>> {
    args.check(M::BINARY)?;
    let a = M::read_model(&args.a)?;
    let b = M::read_model(&args.b)?;
    let blended = M::blend(&a, &b, args.t).map_err(|e| args.mismatch(e))?;
    M::write_model(&args.out, &blended)?;
    println!(
        "wrote {} ({} Gaussians, t = {})",
        args.out.display(),
        M::gaussian_count(&blended),
        args.t
    );
    Ok(())
}

/// The model file of the binaries whose model is one INRIA PLY file (2D, 3D): its Gaussians
/// with their extra properties and comments, and its PLY format, which a blend keeps.
#[derive(Debug)]
pub struct PlyModel {
    /// The Gaussians, extra properties and comments.
    pub ply: PlyGaussians,
    /// ascii or binary, and the byte order.
    pub format: PlyFormat,
}

impl PlyModel {
    /// Reads an INRIA PLY file.
    pub fn read(path: &Path) -> Result<Self, Box<dyn Error>> {
        let (ply, format) = read_ply_with_format(path)?;
        Ok(Self { ply, format })
    }

    /// Writes the PLY file in its format.
    pub fn write(&self, path: &Path) -> Result<(), Box<dyn Error>> {
        Ok(write_ply(path, &self.ply, self.format)?)
    }

    /// The blend of two PLY models ([`interpolate_ply`]) with `a`'s extra properties and format.
    pub fn blend(a: &Self, b: &Self, t: f32) -> Result<Self, String> {
        let ply = interpolate_ply(&a.ply, &b.ply, t).map_err(|e| e.to_string())?;
        Ok(Self {
            ply,
            format: a.format,
        })
    }
}

/// The clap command of `M`'s binary: named after it, its subcommands' help as
/// [`ModalityBinary`] gives it, and a negative number after a flag taken as that flag's value
/// (`--steps -1` is refused naming `--steps`, `--time -0.5` by its own check, instead of read
/// as an unknown flag `-1`).
pub fn command<M: ModalityBinary>() -> clap::Command {
    let (about, long_about) = help_of(M::INTERPOLATE_HELP);
    let command = Cli::<M>::command()
        .name(M::BINARY.name())
        .about(M::ABOUT)
        .mut_subcommand("interpolate", |c| c.about(about).long_about(long_about));
    let command = match M::SELFTEST_HELP {
        Some(text) => command.mut_subcommand("selftest", |c| c.long_about(text)),
        None => command,
    };
    command
        .allow_negative_numbers(true)
        .mut_subcommands(|c| c.allow_negative_numbers(true))
}

/// The command line `args` (the program's name first) of `M`'s binary.
fn parse_from<M: ModalityBinary>(
    args: impl IntoIterator<Item = impl Into<OsString> + Clone>,
) -> Result<Cli<M>, clap::Error> {
    let matches = command::<M>().try_get_matches_from(args)?;
    Cli::from_arg_matches(&matches)
}

/// Runs `M`'s binary: keeps the memory a step frees in the process (a step frees and
/// re-allocates gigabytes of tensors), parses the command line (printing the help or the
/// usage error and exiting as clap does), runs the subcommand, and exits as
/// [`exit_code`] says.
pub fn main<M: ModalityBinary>() -> ExitCode {
    style_loss::memory::keep_freed_memory();
    style_loss::cpu_threads::candle_ops_on_calling_thread();
    let cli = parse_from::<M>(std::env::args_os()).unwrap_or_else(|e| e.exit());
    let result = match &cli.command {
        Command::Stylize(args) => M::stylize(args),
        Command::Own(command) => M::own(command),
        Command::Render(args) => M::render(args),
        Command::Interpolate(args) => interpolate::<M>(args),
        Command::Export(args) => M::export(args),
        Command::Eval(args) => M::eval(args),
        Command::Selftest(args) => args.run(M::self_checks()),
    };
    exit_code(result)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A binary of one own subcommand, `run --steps N --t X`, and the shared ones.
    struct Tiny;

    /// Stylize.
    #[derive(clap::Args, Debug)]
    struct NoFlags {}

    #[derive(clap::Subcommand, Debug)]
    enum TinyCommand {
        /// Run.
        Run {
            #[arg(long)]
            steps: u64,
            #[arg(long)]
            t: f64,
        },
    }

    impl ModalityBinary for Tiny {
        const BINARY: Binary = Binary::Picture;
        const ABOUT: &'static str = "A tiny binary";
        const INTERPOLATE_HELP: &'static str = "Blend two models.\n\nParameter by parameter.";
        type Stylize = NoFlags;
        type Own = TinyCommand;
        type Render = NoFlags;
        type Export = NoFlags;
        type Eval = NoFlags;
        type Model = PlyModel;
        fn read_model(path: &Path) -> Result<PlyModel, Box<dyn Error>> {
            PlyModel::read(path)
        }
        fn write_model(path: &Path, model: &PlyModel) -> Result<(), Box<dyn Error>> {
            model.write(path)
        }
        fn blend(a: &PlyModel, b: &PlyModel, t: f32) -> Result<PlyModel, String> {
            PlyModel::blend(a, b, t)
        }
        fn gaussian_count(model: &PlyModel) -> usize {
            model.ply.gaussians.len()
        }
        fn stylize(_: &NoFlags) -> Result<(), Box<dyn Error>> {
            Ok(())
        }
        fn own(_: &TinyCommand) -> Result<(), Box<dyn Error>> {
            Ok(())
        }
        fn render(_: &NoFlags) -> Result<(), Box<dyn Error>> {
            Ok(())
        }
        fn export(_: &NoFlags) -> Result<(), Box<dyn Error>> {
            Ok(())
        }
        fn eval(_: &NoFlags) -> Result<(), Box<dyn Error>> {
            Ok(())
        }
    }

    #[test]
    fn a_negative_number_is_the_value_of_the_flag_before_it() {
        let parse = |args: &[&str]| parse_from::<Tiny>(args.iter().copied());
        let e = parse(&["x", "run", "--steps", "-1", "--t", "0"])
            .err()
            .expect("refused");
        assert!(
            e.to_string().contains("invalid value '-1' for '--steps"),
            "{e}"
        );
        let cli = parse(&["x", "run", "--steps", "2", "--t", "-0.5"]).unwrap();
        let Command::Own(TinyCommand::Run { steps, t }) = cli.command else {
            panic!("run parses as the binary's own subcommand");
        };
        assert_eq!((steps, t), (2, -0.5));
        let e = parse(&["x", "run", "--bogus"]).err().expect("refused");
        assert!(e.to_string().contains("--bogus"), "{e}");
    }

    #[test]
    fn the_subcommands_are_listed_in_one_order_with_the_binarys_help() {
        let mut command = command::<Tiny>();
        // As `--help` lists them (a changed subcommand keeps its place by its display order).
        let mut listed: Vec<&clap::Command> = command.get_subcommands().collect();
        listed.sort_by_key(|c| c.get_display_order());
        let names: Vec<&str> = listed.iter().map(|c| c.get_name()).collect();
        assert_eq!(
            names,
            [
                "stylize",
                "run",
                "render",
                "interpolate",
                "export",
                "eval",
                "selftest"
            ]
        );
        assert_eq!(command.get_name(), "clipgaussian-2d");
        let interpolate = command.find_subcommand_mut("interpolate").unwrap();
        assert_eq!(
            interpolate.get_about().unwrap().to_string(),
            "Blend two models"
        );
        assert_eq!(
            interpolate.get_long_about().unwrap().to_string(),
            "Blend two models.\n\nParameter by parameter."
        );
        assert_eq!(help_of("One line."), ("One line", None));
    }
}
