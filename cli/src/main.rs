//! `fpm`: the Fourier ptychographic microscope, from LED controller to image.
//!
//! The command line only: parsing, logging set-up and error reporting. Each subcommand
//! lives in its own module and only formats what the library crates do.

mod acquire;
mod bench;
mod calibrate;
mod camera;
mod color;
mod demo;
mod device;
mod doctor;
mod dpc;
mod emulator;
mod flatten;
mod import;
mod progress;
mod reconstruct;
mod scan;
mod serve;
mod shell;
mod simulate;
mod stage;
mod units;
mod virtual_camera;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Fourier ptychographic microscopy: LED controller, calibration and reconstruction.
#[derive(Parser, Debug)]
#[command(name = "fpm", version, propagate_version = true)]
struct Cli {
    /// More log output (-v: info, -vv: debug). RUST_LOG overrides.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run the virtual microscope demo (no hardware needed).
    Demo(demo::DemoArgs),
    /// Talk to an LED controller (board or emulator) over its serial port.
    Device(device::DeviceArgs),
    /// Run the emulated LED controller on a pseudo-terminal.
    Emulator(emulator::EmulatorArgs),
    /// Check this machine for fpm (udev, ports, the board's versions, cameras, shared
    /// memory, disk, the service's port), each finding with the action to take.
    Doctor(doctor::DoctorArgs),
    /// Run a simulated camera on a virtual rig (with `fpm emulator --rig`): renders
    /// each triggered exposure for a hidden, misplaced LED array and publishes frames
    /// on iceoryx2.
    VirtualCamera(virtual_camera::VirtualCameraArgs),
    /// Real cameras: list GenICam cameras, run one into the frame contract.
    #[command(subcommand)]
    Camera(camera::CameraCommand),
    /// Make simulated datasets with the full wave-optics model.
    #[command(subcommand)]
    Simulate(simulate::SimulateCommand),
    /// Calibrate the LED array (pdcFPM) from a defocus dataset.
    Calibrate(calibrate::CalibrateArgs),
    /// Acquire a dataset from a rig (controller + camera on iceoryx2): optional pdcFPM
    /// calibration, every LED labelled, streaming reconstruction.
    Acquire(acquire::AcquireArgs),
    /// Read another lab's FPM data (MATLAB, PtyLab HDF5, TIFF + CSV) into a dataset.
    Import(import::ImportArgs),
    /// Quantitative phase of a weak object (DPC) from a dataset's bright-field frames:
    /// four half-circle patterns, a first look and a focus measure.
    Dpc(dpc::DpcArgs),
    /// Reconstruct amplitude, phase and pupil (EPRY) from a dataset.
    Reconstruct(reconstruct::ReconstructArgs),
    /// Scan a slide: a grid of fields, the stage moving from one to the next, each
    /// acquired (and reconstructed while the next is) and joined into one image.
    Scan(scan::ScanArgs),
    /// Join a scan's fields into one slide image: reconstruct each field (those not
    /// done yet), register them on their overlaps, blend, write OME-Zarr.
    Stitch(scan::StitchArgs),
    /// Motorised stages (GRBL, Marlin, Sangaboard): info, move, home, and an emulator.
    #[command(subcommand)]
    Stage(stage::StageCommand),
    /// Run the acquisition service: a local HTTP/JSON API that queues jobs on the rig.
    Serve(serve::ServeArgs),
    /// Measure performance.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Print a shell completion script (e.g. `fpm completions bash >
    /// ~/.local/share/bash-completion/completions/fpm`).
    Completions(shell::CompletionsArgs),
    /// Write man pages (fpm.1 and one per subcommand) into a directory.
    Man(shell::ManArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // `fpm device status | head` should end quietly like any Unix tool, not panic on a
    // closed pipe. Not for the long-running services, which write to child processes
    // and report a child that went away themselves.
    if !matches!(
        cli.command,
        Command::Emulator(_)
            | Command::VirtualCamera(_)
            | Command::Demo(_)
            | Command::Serve(_)
            | Command::Camera(camera::CameraCommand::Run(_))
    ) {
        // SAFETY: set before any thread exists; the default action only ends the process.
        unsafe {
            let _ = nix::sys::signal::signal(
                nix::sys::signal::Signal::SIGPIPE,
                nix::sys::signal::SigHandler::SigDfl,
            );
        }
    }
    init_logging(&cli);
    let result = match cli.command {
        Command::Demo(args) => demo::run(args),
        Command::Device(args) => device::run(args),
        Command::Emulator(args) => emulator::run(args),
        Command::Doctor(args) => doctor::run(args),
        Command::VirtualCamera(args) => virtual_camera::run(args),
        Command::Camera(cmd) => camera::run(cmd),
        Command::Simulate(cmd) => simulate::run(cmd),
        Command::Calibrate(args) => calibrate::run(args),
        Command::Stage(cmd) => stage::run(cmd),
        Command::Stitch(args) => scan::stitch(args),
        Command::Scan(args) => scan::scan(args),
        Command::Import(args) => import::run(args),
        Command::Dpc(args) => dpc::run(args),
        Command::Reconstruct(args) => reconstruct::run(args),
        Command::Acquire(args) => acquire::run(args),
        Command::Serve(args) => serve::run(args),
        Command::Bench(cmd) => bench::run(cmd),
        Command::Completions(args) => shell::completions(args),
        Command::Man(args) => shell::man(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Logs on stderr: warnings by default (info for the long-running services), more
/// with -v/-vv, RUST_LOG over all; iceoryx2's own log at the matching level.
fn init_logging(cli: &Cli) {
    let default_level = match (&cli.command, cli.verbose) {
        (
            Command::Emulator(_)
            | Command::VirtualCamera(_)
            | Command::Serve(_)
            | Command::Camera(camera::CameraCommand::Run(_)),
            0,
        ) => "info",
        (_, 0) => "warn",
        (_, 1) => "info",
        _ => "debug",
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
                // postcard-rpc warns when the link closes; we report that ourselves.
                tracing_subscriber::EnvFilter::new(format!("{default_level},postcard_rpc=error"))
            }),
        )
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(std::io::stderr)
        .init();
    // iceoryx2 logs on its own: only its errors, unless asked for more.
    fpm_frames::set_ipc_log_level(match cli.verbose {
        0 => fpm_frames::LogLevel::Error,
        1 => fpm_frames::LogLevel::Warn,
        _ => fpm_frames::LogLevel::Debug,
    });
}
