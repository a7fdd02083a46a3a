//! How commands put their results out: text or JSON on stdout (a closed pipe is not an
//! error), or a file written atomically; progress bars that JSON runs hide.

use std::path::PathBuf;

use anyhow::{Context, Result};
use serde::Serialize;

use super::progress::bar;

/// Writes `text` to stdout; a closed pipe (`sylva ... | head`) ends the output quietly
/// instead of panicking.
pub fn emit(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|_| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => Ok(r?),
    }
}

pub fn emit_to(text: &str, out: Option<PathBuf>) -> Result<()> {
    match out {
        Some(path) => sylva_core::atomic_write(&path, text.as_bytes())
            .with_context(|| format!("writing {}", path.display())),
        None => {
            print!("{text}");
            Ok(())
        }
    }
}

/// A bar of `len` steps, hidden when stdout is for JSON.
pub fn bench_bar(json: bool, len: usize, what: &str) -> indicatif::ProgressBar {
    if json {
        indicatif::ProgressBar::hidden()
    } else {
        bar(len as u64, what)
    }
}

/// A report on stdout: one line of JSON (`json`) or its text.
pub fn print_report<R: Serialize + std::fmt::Display>(r: &R, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(r)?);
    } else {
        print!("{r}");
    }
    Ok(())
}

/// A report on stdout through [`emit`]: pretty JSON, keys sorted (`json`), or its text.
pub fn emit_report<R: Serialize + std::fmt::Display>(r: &R, json: bool) -> Result<()> {
    if json {
        return emit(&format!("{}\n", pretty_json(r)?));
    }
    emit(&r.to_string())
}

/// `r` as pretty JSON, keys sorted (as `serde_json::json!` objects print them).
pub fn pretty_json<R: Serialize>(r: &R) -> Result<String> {
    Ok(serde_json::to_string_pretty(&serde_json::to_value(r)?)?)
}
