//! The `weft` binary: everything lives in [`weft_cli::run`].

fn main() -> std::process::ExitCode {
    // Like other Unix tools, end quietly when the reader of our output goes
    // away (`weft info … | head`): Rust ignores SIGPIPE, so a write would
    // fail and `println!` panic; restore the default action (terminate).
    let _ = signal_hook::flag::register_conditional_default(
        signal_hook::consts::SIGPIPE,
        std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true)),
    );
    weft_cli::run(std::env::args_os())
}
