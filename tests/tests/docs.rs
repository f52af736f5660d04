//! The guide's commands still run: every `$ fpm …` line in a ```console block of the
//! README and docs/ is parsed by the real `fpm` (flags and values checked, as
//! `fpm … --help` does before anything runs), and the cheap ones run for real, in
//! order, each chapter in its own scratch directory standing in for /tmp.

use std::path::{Path, PathBuf};
use std::process::Command;

use fpm_tests::{fpm_bin, TempDir};

/// The `$ fpm …` lines of the ```console blocks of `file`, as argument lists.
fn commands(file: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(file).unwrap();
    let mut out = vec![];
    let mut in_console = false;
    for line in text.lines() {
        let fence = line.trim_start();
        if fence.starts_with("```") {
            in_console = !in_console && fence.trim_start_matches('`').starts_with("console");
            continue;
        }
        if let Some(command) = line.strip_prefix("$ fpm ").filter(|_| in_console) {
            out.push(split(command));
        }
    }
    out
}

/// Shell words: whitespace-separated, single or double quotes kept together; a `#`
/// starting a word begins a comment.
fn split(line: &str) -> Vec<String> {
    let (mut words, mut word, mut quote, mut any) = (vec![], String::new(), None, false);
    for c in line.chars() {
        match (quote, c) {
            (None, '#') if !any => break,
            (None, '\'' | '"') => (quote, any) = (Some(c), true),
            (Some(q), c) if c == q => quote = None,
            (None, c) if c.is_whitespace() => {
                if any {
                    words.push(std::mem::take(&mut word));
                }
                any = false;
            }
            (_, c) => (word, any) = (word + &c.to_string(), true),
        }
    }
    if any {
        words.push(word);
    }
    words
}

/// A line that is shell beyond one command (pipes, redirections, substitutions) or
/// has a placeholder for the reader to fill in.
fn not_one_command(args: &[String]) -> bool {
    args.iter().any(|a| {
        a == "&"
            || ["|", ">", "<", "&&", ";", "$("]
                .iter()
                .any(|s| a.starts_with(s))
            || a.chars().any(|c| c.is_ascii_uppercase())
                && a.chars()
                    .all(|c| c.is_ascii_uppercase() || "_.-/".contains(c))
    })
}

/// Cheap enough to run for real: what makes and reads small simulated sets, and the
/// small vendored real set (the full real frame's reconstruction has its own tests).
fn cheap(args: &[String]) -> bool {
    let sub: Vec<&str> = args.iter().take(2).map(String::as_str).collect();
    let size_ok = args
        .windows(2)
        .find(|w| w[0] == "--size")
        .is_none_or(|w| w[1].parse::<usize>().is_ok_and(|s| s <= 256));
    match sub.as_slice() {
        ["simulate", _] => size_ok,
        ["calibrate", _] | ["completions", _] | ["man", _] => true,
        ["reconstruct", dir] => {
            !args
                .iter()
                .any(|a| a == "--refine-leds" || a == "--camera-gamma")
                && (dir.starts_with("/tmp/") || dir.starts_with("data/zuo-usaf"))
        }
        _ => false,
    }
}

#[test]
fn the_guides_commands_parse_and_the_cheap_ones_run() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut files: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    files.sort();
    files.push(root.join("README.md"));
    let (mut parsed, mut ran) = (0, 0);
    for file in &files {
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        let scratch = TempDir::new(&format!("docs-{}", name.trim_end_matches(".md")));
        let tmp = format!("{}/", scratch.0.display());
        for args in commands(file) {
            if not_one_command(&args) {
                continue;
            }
            let args: Vec<String> = args.iter().map(|a| a.replace("/tmp/", &tmp)).collect();
            // Flags and values as written: `--help` at the end makes clap check every
            // argument before it and stop.
            let help = Command::new(fpm_bin())
                .args(&args)
                .arg("--help")
                .current_dir(&root)
                .output()
                .unwrap();
            assert!(
                help.status.success(),
                "{name}: `fpm {}` does not parse:\n{}",
                args.join(" "),
                String::from_utf8_lossy(&help.stderr)
            );
            parsed += 1;
            if cheap(&args) {
                let run = Command::new(fpm_bin())
                    .args(&args)
                    .current_dir(&root)
                    .output()
                    .unwrap();
                assert!(
                    run.status.success(),
                    "{name}: `fpm {}` failed:\n{}",
                    args.join(" "),
                    String::from_utf8_lossy(&run.stderr)
                );
                ran += 1;
            }
        }
    }
    println!("{parsed} documented commands parse, {ran} cheap ones ran");
    assert!(
        parsed >= 40 && ran >= 8,
        "{parsed} parsed, {ran} ran: the guide lost its commands?"
    );
}
