//! `fpm completions SHELL` and `fpm man --out DIR`: generated from the same clap
//! definitions the commands parse with, so they never fall behind.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, CommandFactory};

/// `fpm completions`.
#[derive(Args, Debug)]
pub struct CompletionsArgs {
    /// The shell: bash, zsh, fish, elvish or powershell.
    shell: clap_complete::Shell,
}

/// `fpm man`.
#[derive(Args, Debug)]
pub struct ManArgs {
    /// Directory for the pages: fpm.1 and one per subcommand (fpm-reconstruct.1, …).
    #[arg(long)]
    out: PathBuf,
}

/// Write the completion script for `a.shell` to stdout.
pub fn completions(a: CompletionsArgs) -> Result<()> {
    let mut cmd = crate::Cli::command();
    clap_complete::generate(a.shell, &mut cmd, "fpm", &mut std::io::stdout());
    Ok(())
}

/// Write the man pages into `a.out`.
pub fn man(a: ManArgs) -> Result<()> {
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    clap_mangen::generate_to(crate::Cli::command(), &a.out)
        .with_context(|| format!("writing man pages to {}", a.out.display()))?;
    println!(
        "wrote man pages to {} (man -l {}/fpm.1)",
        a.out.display(),
        a.out.display()
    );
    Ok(())
}
