//! The `knitvox` binary: parse the command line, run it, map errors to the
//! documented exit codes (see `knitvox::cli::exit`).

use clap::Parser;
use knitvox::cli::{self, error_message, exit_code_for, Cli, ExitCode};

fn main() -> std::process::ExitCode {
    // Like other Unix tools, end quietly when the reader of our output goes away
    // (`knitvox inspect ... | head`) instead of panicking on a broken pipe.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // SIGINT/SIGTERM (a farm killing a task): remove the temporary files of
    // writes in flight, then die of the signal as usual.
    #[cfg(unix)]
    // SAFETY: installing an async-signal-safe handler before any thread starts.
    unsafe {
        let handler =
            knitvox::io::atomic::remove_temporaries_on_signal as extern "C" fn(libc::c_int);
        libc::signal(libc::SIGINT, handler as libc::sighandler_t);
        libc::signal(libc::SIGTERM, handler as libc::sighandler_t);
    }
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return std::process::ExitCode::from(if e.use_stderr() {
                ExitCode::Usage.code()
            } else {
                0
            });
        }
    };
    // A panic is a bug: report it and exit with the internal-error code, not 101.
    let outcome = std::panic::catch_unwind(|| cli::run(cli));
    let code = match outcome {
        Ok(Ok(code)) => code,
        Ok(Err(e)) => {
            eprintln!("error: {}", error_message(&e));
            exit_code_for(&e)
        }
        Err(_) => {
            eprintln!("error: internal error (a bug in knitvox; please report it with the input that caused it)");
            ExitCode::Internal
        }
    };
    std::process::ExitCode::from(code.code())
}
