//! `fpm`: the Fourier ptychographic microscope, from LED controller to image.
fn main() -> std::process::ExitCode {
    fpm_host::cli::main()
}
