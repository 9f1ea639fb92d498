//! The progress bar of drive-sim's long runs: on stderr, and only when stderr is a terminal, so that a pipe or a
//! CI log gets nothing from it and stdout (whose last lines are the `key=value` figures) never does.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A progress bar that is drawn, or nothing where stderr is not a terminal.
pub struct Progress {
    bar: Option<ProgressBar>,
}

impl Progress {
    /// A bar named `what` on stderr if stderr is a terminal, otherwise one that shows nothing.
    pub fn on_terminal(what: &str) -> Self {
        Self::shown_if(std::io::stderr().is_terminal(), what)
    }

    /// A bar on stderr if `shown`, otherwise one that shows nothing.
    fn shown_if(shown: bool, what: &str) -> Self {
        let bar = shown.then(|| {
            let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
            let style = ProgressStyle::with_template("{msg} [{elapsed_precise}] {wide_bar} {percent:>3}% (eta {eta})")
                .unwrap_or_else(|_| ProgressStyle::default_bar());
            bar.set_style(style);
            bar.set_message(what.to_owned());
            bar
        });
        Self { bar }
    }

    /// `done` of `total` steps (the observer the scenarios take).
    pub fn update(&mut self, done: u64, total: u64) {
        if let Some(bar) = &self.bar {
            bar.set_length(total);
            bar.set_position(done);
        }
    }

    /// Removes the bar from the terminal before the report's figures are printed.
    pub fn finish(self) {
        if let Some(bar) = self.bar {
            bar.finish_and_clear();
        }
    }
}
