//! The `weft` binary: everything lives in [`weft_cli::run`].

fn main() -> std::process::ExitCode {
    weft_cli::run(std::env::args_os())
}
