//! One skeleton for the four binaries: their subcommands in one order (`stylize`, the
//! modality's own ones such as `fit`, `render`, `interpolate`, `export`, `eval`, `selftest`),
//! the parsing of the command line and the dispatch, and the process's start and exit. A
//! binary is its modality's part only: an implementation of [`ModalityBinary`] (the flags of
//! its subcommands, whose doc comments are their help, and what each does) and
//! `fn main() -> ExitCode { gs_stylize::binary::main::<Its>() }`.

use std::error::Error;
use std::ffi::OsString;
use std::process::ExitCode;

use clap::{Args, CommandFactory, FromArgMatches, Parser, Subcommand};

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

    /// Runs `stylize`.
    fn stylize(args: &Self::Stylize) -> Result<(), Box<dyn Error>>;
    /// Runs one of the modality's own subcommands.
    fn own(command: &Self::Own) -> Result<(), Box<dyn Error>>;
    /// Runs `render`.
    fn render(args: &Self::Render) -> Result<(), Box<dyn Error>>;
    /// Runs `interpolate`: by default the blend of two PLY files of the same Gaussians
    /// ([`InterpolateArgs::run`]), the line it returns printed.
    fn interpolate(args: &InterpolateArgs) -> Result<(), Box<dyn Error>> {
        args.run(Self::BINARY).map(|line| println!("{line}"))
    }
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
        Command::Interpolate(args) => M::interpolate(args),
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
