//! The `knitvox` binary: parse the command line, run it, map errors to the
//! documented exit codes (see `knitvox::cli::exit`).

use clap::Parser;
use knitvox::cli::exit::{class_for, error_file, error_json};
use knitvox::cli::{self, error_message, exit_code_for, Cli, ExitCode};
use knitvox::pipeline::ErrorClass;

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
    // Mesa's Vulkan device-select layer connects to a Wayland display to rank
    // GPUs and, on a headless farm node, prints "error: XDG_RUNTIME_DIR is
    // invalid or not set" twice while knitvox probes for a GPU. knitvox
    // picks its adapter itself, so the layer is switched off unless the user
    // set it (single-threaded here, so setting the variable is sound).
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
    // With --json, errors are a JSON object on stdout as well.
    let json = cli::wants_json(std::env::args_os());
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            // Help and version go out whole; an error is cut short like
            // every other (a 10 MB argument quoted back).
            let plain = e.to_string();
            if e.use_stderr() && plain.len() > knitvox::geom::MAX_MESSAGE_BYTES {
                eprint!("{}", cli::exit::short(&plain));
            } else {
                let _ = e.print();
            }
            if json && e.use_stderr() {
                let text = e.kind().to_string();
                let message = plain;
                let first = message.lines().next().unwrap_or(&text);
                let first = first.strip_prefix("error: ").unwrap_or(first);
                println!("{}", error_json(ErrorClass::Usage, first, None));
            }
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
            let message = error_message(&e);
            eprintln!("error: {message}");
            if json {
                println!(
                    "{}",
                    error_json(class_for(&e), &message, error_file(&e).as_deref())
                );
            }
            exit_code_for(&e)
        }
        Err(_) => {
            let message =
                "internal error (a bug in knitvox; please report it with the input that caused it)";
            eprintln!("error: {message}");
            if json {
                println!("{}", error_json(ErrorClass::Internal, message, None));
            }
            ExitCode::Internal
        }
    };
    std::process::ExitCode::from(code.code())
}
