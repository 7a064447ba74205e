//! Progress bars for the long jobs a user waits on (`eval` over many bags, `adapt --judge`,
//! `bias-memory`): drawn on a terminal's stderr only, so a log file or a pipe gets none.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A bar over `len` steps prefixed `what`; hidden off a terminal, and for a single step (over
/// as soon as it shows).
pub fn bar(len: usize, what: &str) -> ProgressBar {
    let bar = if len > 1 && std::io::stderr().is_terminal() {
        ProgressBar::new(len as u64)
    } else {
        ProgressBar::with_draw_target(Some(len as u64), ProgressDrawTarget::hidden())
    };
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} {msg} ({elapsed}, ~{eta} left)")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_prefix(what.to_string());
    bar
}
