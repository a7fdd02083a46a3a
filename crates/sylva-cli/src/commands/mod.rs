//! One module per `sylva` command.

use std::process::ExitCode;
use std::sync::OnceLock;

use sylva_render::StageClock;

/// The clock of `sylva render`'s stage summary and `bench trace --json`: installed on first
/// use as the process's global `tracing` subscriber. The binary installs it, not a library:
/// libraries only open spans.
pub fn stage_clock() -> &'static StageClock {
    static CLOCK: OnceLock<StageClock> = OnceLock::new();
    CLOCK.get_or_init(|| {
        use tracing_subscriber::layer::SubscriberExt;
        let clock = StageClock::new();
        let subscriber = tracing_subscriber::registry().with(clock.clone());
        // Fails only if another subscriber is installed; then nothing is timed.
        let _ = tracing::subscriber::set_global_default(subscriber);
        clock
    })
}

/// Prints an error chain the way users expect (`error: ...` then `caused by: ...`) and maps it
/// to the exit code.
pub fn finish(result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprint!("{}", error_report("error: ", &e));
            ExitCode::FAILURE
        }
    }
}

/// `e` as `{head}message` then one `  caused by: ...` line per cause, each line ending in a
/// newline. A cause whose text a line above already holds is left out: most errors here put
/// their source's message into their own (`cannot write x.png: Permission denied`), so
/// printing the chain as it is would say everything twice.
pub fn error_report(head: &str, e: &anyhow::Error) -> String {
    let mut report = format!("{head}{e}\n");
    for cause in e.chain().skip(1) {
        let text = cause.to_string();
        if !report.contains(&text) {
            report.push_str(&format!("  caused by: {text}\n"));
        }
    }
    report
}

pub mod basis;
pub mod bench;
pub mod bench_rays;
pub mod bench_relight;
pub mod bench_scene;
pub mod bench_spp;
pub mod bench_trace;
pub mod bench_voxel;
pub mod budget;
pub mod device;
pub mod export;
pub mod lb;
pub mod output;
pub mod progress;
pub mod relight;
pub mod render;
pub mod scene;
pub mod species;
pub mod spp;
pub mod spp_trees;
pub mod sun_time;
pub mod view;
pub mod voxelize;

#[cfg(test)]
mod tests {
    use super::error_report;

    /// An error that writes its source's message into its own, as most of sylva's do.
    #[derive(Debug)]
    struct Wrapper(std::io::Error);

    impl std::fmt::Display for Wrapper {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            write!(f, "cannot write x.png: {}", self.0)
        }
    }

    impl std::error::Error for Wrapper {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            Some(&self.0)
        }
    }

    /// Issue 31 item 8: a cause already in the message above is not printed again; a cause
    /// that adds something is.
    #[test]
    fn causes_already_in_the_message_are_not_repeated() {
        let io = std::io::Error::new(std::io::ErrorKind::PermissionDenied, "Permission denied");
        let e = anyhow::Error::new(Wrapper(io));
        assert_eq!(
            error_report("error: ", &e),
            "error: cannot write x.png: Permission denied\n"
        );
        let e = anyhow::Error::new(Wrapper(std::io::Error::other("disk full")))
            .context("rendering frame 3");
        assert_eq!(
            error_report("error: ", &e),
            "error: rendering frame 3\n  caused by: cannot write x.png: disk full\n"
        );
    }
}
