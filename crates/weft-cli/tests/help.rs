//! `docs/cli.md` holds the `--help` text of `weft` and of every subcommand,
//! rendered at a fixed width of 100 columns; this test fails when the two
//! drift apart. After changing the CLI, regenerate the document with
//! `WEFT_BLESS=1 cargo nextest run -p weft-cli --test help` and review the diff.

use std::path::{Path, PathBuf};
use std::process::Command;

const COMMANDS: &[&str] = &[
    "",
    "run",
    "render",
    "plot",
    "check",
    "info",
    "bench",
    "ccd-bench",
];

fn doc_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/cli.md")
}

fn help(cmd: &str) -> String {
    let mut c = Command::new(env!("CARGO_BIN_EXE_weft"));
    if !cmd.is_empty() {
        c.arg(cmd);
    }
    let o = c.arg("--help").output().expect("weft runs");
    assert!(o.status.success(), "weft {cmd} --help failed");
    String::from_utf8(o.stdout).expect("UTF-8 help")
}

fn render_doc() -> String {
    let mut doc = String::from(
        "# The `weft` command line\n\n\
         The help of every command, as `weft … --help` prints it (at 100 columns).\n\
         A test (`crates/weft-cli/tests/help.rs`) keeps this page and the code in step;\n\
         regenerate it with `WEFT_BLESS=1 cargo nextest run -p weft-cli --test help`.\n",
    );
    for cmd in COMMANDS {
        let title = if cmd.is_empty() {
            "weft".to_string()
        } else {
            format!("weft {cmd}")
        };
        doc.push_str(&format!("\n## `{title}`\n\n```text\n{}```\n", help(cmd)));
    }
    doc
}

#[test]
fn docs_cli_md_matches_the_help_text() {
    let want = render_doc();
    if std::env::var_os("WEFT_BLESS").is_some() {
        std::fs::write(doc_path(), &want).unwrap();
        return;
    }
    let have = std::fs::read_to_string(doc_path()).unwrap_or_default();
    if have != want {
        let line = have
            .lines()
            .zip(want.lines())
            .position(|(a, b)| a != b)
            .unwrap_or_else(|| have.lines().count().min(want.lines().count()));
        panic!(
            "docs/cli.md differs from `weft --help` from line {}:\n  doc:  {:?}\n  help: {:?}\n\
             regenerate it with WEFT_BLESS=1 cargo nextest run -p weft-cli --test help",
            line + 1,
            have.lines().nth(line),
            want.lines().nth(line)
        );
    }
}

#[test]
fn help_is_wrapped_at_100_columns() {
    for cmd in COMMANDS {
        for line in help(cmd).lines() {
            assert!(line.chars().count() <= 100, "weft {cmd} --help: {line:?}");
        }
    }
}
