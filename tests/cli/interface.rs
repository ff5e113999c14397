//! The command-line interface itself: every subcommand's `--help` of both binaries has an
//! example, `imulab completions` writes a script naming every subcommand, and `imulab man`
//! writes one page per (sub)command that is valid roff.

use std::process::Command;

fn imulab() -> Command {
    Command::new(env!("CARGO_BIN_EXE_imulab"))
}

/// Every command of the tree under `cmd` (itself included), with its full name
/// (`imulab allan`), skipping clap's generated `help` subcommand.
fn walk(cmd: &clap::Command, prefix: &str, out: &mut Vec<(String, clap::Command)>) {
    let name = if prefix.is_empty() {
        cmd.get_name().to_string()
    } else {
        format!("{prefix} {}", cmd.get_name())
    };
    out.push((name.clone(), cmd.clone()));
    for sub in cmd.get_subcommands().filter(|s| s.get_name() != "help") {
        walk(sub, &name, out);
    }
}

fn all_commands() -> Vec<(String, clap::Command)> {
    let mut out = Vec::new();
    for mut root in [imulab::cli::app::command(), imulab::daemon::args::command()] {
        root.build();
        walk(&root, "", &mut out);
    }
    out
}

fn imulab_subcommands() -> Vec<String> {
    imulab::cli::app::command()
        .get_subcommands()
        .map(|s| s.get_name().to_string())
        .collect()
}

#[test]
fn every_help_has_an_example() {
    let commands = all_commands();
    assert!(
        commands.len() > 12,
        "walked only {} commands",
        commands.len()
    );
    let missing: Vec<&str> = commands
        .iter()
        .filter(|(_, cmd)| {
            !cmd.clone()
                .render_long_help()
                .to_string()
                .contains("Example")
        })
        .map(|(name, _)| name.as_str())
        .collect();
    assert!(missing.is_empty(), "--help without an example: {missing:?}");
    // And the binary prints it, as a user sees it.
    let out = imulab().args(["man", "--help"]).output().unwrap();
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("Example: imulab man"));
}

#[test]
fn bash_completion_names_every_subcommand() {
    let out = imulab().args(["completions", "bash"]).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let script = String::from_utf8(out.stdout).unwrap();
    assert!(
        script.contains("complete -F"),
        "not a bash completion script"
    );
    let subcommands = imulab_subcommands();
    assert!(subcommands.contains(&"completions".to_string()));
    // The words offered after `imulab `, and a completion branch for each subcommand.
    let top = script
        .lines()
        .find(|l| l.contains("opts=\"") && l.contains("--version"))
        .expect("top-level word list");
    let words: Vec<&str> = top.split(['"', ' ']).collect();
    for sub in &subcommands {
        assert!(
            words.contains(&sub.as_str()),
            "`imulab {sub}` not offered: {top}"
        );
        assert!(
            script.contains(&format!("imulab,{sub})")),
            "no completion branch for `imulab {sub}`"
        );
    }

    let out = imulab()
        .args(["completions", "bash", "--program", "imulogd"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let script = String::from_utf8(out.stdout).unwrap();
    assert!(
        script.contains("imulogd") && script.contains("--check-config"),
        "{script}"
    );

    for shell in ["zsh", "fish", "elvish", "powershell"] {
        let out = imulab().args(["completions", shell]).output().unwrap();
        assert!(out.status.success(), "{shell}");
        let script = String::from_utf8_lossy(&out.stdout);
        assert!(
            script.contains("inspect") && script.contains("allan"),
            "{shell}"
        );
    }
}

#[test]
fn man_pages_render_for_every_command() {
    let dir = tempfile::tempdir().unwrap();
    let out = imulab().arg("man").arg(dir.path()).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut expected = vec!["imulab.1".to_string(), "imulogd.1".to_string()];
    expected.extend(imulab_subcommands().iter().map(|s| format!("imulab-{s}.1")));
    let man = which("man");
    for page in &expected {
        let path = dir.path().join(page);
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{page}: {e}"));
        let title = page.trim_end_matches(".1");
        assert!(
            text.lines()
                .any(|l| l.starts_with(&format!(".TH {title} 1"))),
            "{page}: no roff .TH header for {title}"
        );
        assert!(
            text.contains(".SH NAME") && text.contains(".SH SYNOPSIS"),
            "{page}"
        );
        assert!(text.contains("Example"), "{page}: no example");
        if let Some(man) = &man {
            let shown = Command::new(man)
                .arg("-l")
                .arg(&path)
                .env("MANPAGER", "cat")
                .env("MANWIDTH", "100")
                .output()
                .unwrap();
            let shown_text = String::from_utf8_lossy(&shown.stdout);
            assert!(
                shown.status.success(),
                "man -l {page}: {}",
                String::from_utf8_lossy(&shown.stderr)
            );
            assert!(
                shown_text.contains("NAME") && shown_text.contains("Example"),
                "man -l {page}: {shown_text}"
            );
        }
    }
    if man.is_none() {
        eprintln!("skipped rendering with `man -l`: no `man` on PATH (roff headers checked)");
    }
    let written = std::fs::read_dir(dir.path()).unwrap().count();
    assert_eq!(
        written,
        expected.len(),
        "unexpected pages besides {expected:?}"
    );
}

fn which(program: &str) -> Option<std::path::PathBuf> {
    std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|p| p.join(program))
            .find(|p| p.is_file())
    })
}
