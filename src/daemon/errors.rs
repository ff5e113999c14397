//! How the binaries print an error: the context chain on one line with repeated parts
//! removed (an error whose text already holds its source's text would otherwise print the
//! same words twice), plus, for a bare operating-system error on a path, one line on what to
//! do. Messages that already carry their own advice (serial ports, sessions) are left as they
//! are.

use std::io;

/// The text to print for `err` (without the program name): one or two lines.
pub fn render(err: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in err.chain() {
        let part = cause.to_string();
        if part.is_empty() || text.contains(&part) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&part);
    }
    if let Some(hint) = hint(err) {
        text.push_str("\nhint: ");
        text.push_str(hint);
    }
    text
}

/// Advice for the plain OS errors a user causes with a path, when nothing more specific
/// was said: the error must come straight from the OS (an `io::Error` without a custom text).
fn hint(err: &anyhow::Error) -> Option<&'static str> {
    let io = err
        .chain()
        .find_map(|c| c.downcast_ref::<io::Error>())
        .filter(|e| e.raw_os_error().is_some())?;
    Some(match io.kind() {
        io::ErrorKind::NotFound => {
            "check the path (spelling, current directory); `ls` the directory it should be in"
        }
        io::ErrorKind::PermissionDenied => {
            "check the permissions (`ls -l PATH`); read it as its owner or ask for access"
        }
        io::ErrorKind::IsADirectory => "give a file inside that directory, not the directory",
        io::ErrorKind::NotADirectory => "give a directory here, not a file",
        io::ErrorKind::AlreadyExists => "choose another output path or remove the old one first",
        io::ErrorKind::StorageFull => "free some space or write somewhere else",
        _ => return None,
    })
}
