//! dvrk-sidecar: reads a dVRK PSM, corrects joints 1-2 for instrument-shaft compliance and
//! backlash (Chrysilla et al.), and publishes raw and compensated joint and tip states over
//! iceoryx2 shared memory. Also carries the offline tools of the paper's workflow.

use dvrk_sidecar::{bridge_cmd, calib, drive, echo, offline, serve, simcmd};

use std::path::PathBuf;

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "dvrk-sidecar", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the service: read, compensate, publish every cycle until SIGTERM/SIGINT.
    Serve {
        /// Service configuration file.
        #[arg(long, default_value = "config/sidecar.toml")]
        config: PathBuf,
    },
    /// Load and validate a configuration and every file it names; exit 0 when all is well.
    CheckConfig {
        #[arg(long, default_value = "config/sidecar.toml")]
        config: PathBuf,
    },
    /// Print samples of one of the service's topics, like `ros2 topic echo`.
    Echo(echo::EchoArgs),
    /// Forward kinematics: print the tip pose (RCM frame, CRTK local/measured_cp) for q1..q6.
    Fk(offline::FkArgs),
    /// Apply the compliance model to one measured position and effort.
    Correct(offline::CorrectArgs),
    /// Run the board emulator of the simulated PSM on a UDP socket until SIGTERM/SIGINT.
    Sim(simcmd::SimArgs),
    /// Console stand-in for tests and benches: discover the emulated boards, then read them and
    /// write zero current every cycle like the dVRK console (loopback only).
    Drive(drive::DriveArgs),
    /// Run a calibration procedure on the simulator, or record one from a real robot.
    Calibrate(calib::CalibrateArgs),
    /// Fit compliance parameters from calibration data (paper sections 3-4).
    Fit(calib::FitArgs),
    /// Evaluate the correction on divot-push data (drift, tip error; paper Figs. 7-8).
    Evaluate(calib::EvaluateArgs),
    /// Publish the compensated topics to ROS 2 over DDS (no ROS installation needed).
    #[command(name = "ros2-bridge")]
    Ros2Bridge(bridge_cmd::Ros2BridgeArgs),
    /// Record the compensated topics to an MCAP file (ROS 2 schemas, CDR payloads).
    Record(bridge_cmd::RecordArgs),
}

/// Logging is set up once, here: fmt to stderr (systemd passes it to the journal), filtered by
/// RUST_LOG (default `info`).
fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .init();
}

/// `--out` of any command: refused at parse time, before any work, when it is a directory or
/// its directory does not exist.
fn output_path(s: &str) -> Result<PathBuf, String> {
    let p = PathBuf::from(s);
    dvrk_sidecar::calib::data::check_output_path(&p).map_err(|e| format!("{e:#}"))?;
    Ok(p)
}

/// Lets every option that takes a value, in every subcommand, take a negative number
/// (`--tau-min-nm -1`, `--offset -0.5`), and checks every `--out` before any work: set once
/// here, so no option can forget it.
fn allow_negative_numbers(cmd: clap::Command) -> clap::Command {
    let cmd = cmd.mut_args(|a| {
        let a = if a.get_id() == "out" {
            a.value_parser(output_path)
        } else {
            a
        };
        if a.get_action().takes_values() {
            a.allow_negative_numbers(true)
        } else {
            a
        }
    });
    let names: Vec<String> = cmd
        .get_subcommands()
        .map(|s| s.get_name().to_owned())
        .collect();
    names
        .into_iter()
        .fold(cmd, |c, n| c.mut_subcommand(n, allow_negative_numbers))
}

fn parse_cli() -> Cli {
    use clap::{CommandFactory, FromArgMatches};
    let matches = allow_negative_numbers(Cli::command()).get_matches();
    Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit())
}

fn main() -> std::process::ExitCode {
    let cli = parse_cli();
    init_tracing();
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // The reader of stdout went away (`| head -1`): done, not failed (see dvrk_sidecar::out).
        Err(e) if dvrk_sidecar::out::is_stdout_closed(&e) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Serve { config } => serve::run(&config),
        Command::CheckConfig { config } => serve::check_config(&config),
        Command::Echo(args) => echo::run(&args),
        Command::Fk(args) => offline::fk(&args),
        Command::Correct(args) => offline::correct(&args),
        Command::Sim(args) => simcmd::run(&args),
        Command::Drive(args) => drive::run(&args),
        Command::Calibrate(args) => calib::run_calibrate(&args),
        Command::Fit(args) => calib::run_fit(&args),
        Command::Evaluate(args) => calib::run_evaluate(&args),
        Command::Ros2Bridge(args) => bridge_cmd::run_ros2_bridge(&args),
        Command::Record(args) => bridge_cmd::run_record(&args),
    }
}

#[cfg(test)]
mod tests {
    /// clap checks its own rules (unique argument ids, ...) only when a command is parsed:
    /// check every subcommand here rather than in a user's terminal.
    #[test]
    fn the_command_line_definition_is_consistent() {
        use clap::CommandFactory;
        super::Cli::command().debug_assert();
    }
}
