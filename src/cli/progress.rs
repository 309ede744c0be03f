//! [`Progress`]: the progress report of the long commands. On a terminal, an
//! indicatif bar; otherwise (a Slurm log, a file, a pipe) one plain line at a
//! steady interval, written by a timer thread so it keeps coming while a long
//! step runs: `progress: <done>/<total> <unit> (<pct>%), <rate>/s, eta <t>,
//! elapsed <t>[, <message>]`, no ANSI codes. The interval is
//! `DSMSTREAM_PROGRESS_SECS` (seconds, default 10; 0 turns the lines off).
//! `-q` hides both forms.

use std::io::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam::channel::{bounded, RecvTimeoutError, Sender};
use indicatif::ProgressBar;

/// Seconds between plain lines unless `DSMSTREAM_PROGRESS_SECS` says otherwise.
pub const DEFAULT_INTERVAL_S: f64 = 10.0;

/// What the plain lines report, shared with the timer thread.
struct State {
    unit: String,
    total: AtomicU64,
    done: AtomicU64,
    message: Mutex<String>,
    started: Instant,
}

impl State {
    /// One plain line, e.g. `progress: 120/480 pairs (25.0%), 3.2/s, eta 1m52s, elapsed 37s, cache hit 87%`.
    fn line(&self) -> String {
        let (done, total) = (
            self.done.load(Ordering::Relaxed),
            self.total.load(Ordering::Relaxed),
        );
        let elapsed = self.started.elapsed().as_secs_f64();
        let rate = done as f64 / elapsed.max(1e-9);
        let mut line = if total > 0 {
            let eta = if rate > 0.0 {
                clock(total.saturating_sub(done) as f64 / rate)
            } else {
                "?".into()
            };
            format!(
                "progress: {done}/{total} {} ({:.1}%), {rate:.2}/s, eta {eta}, elapsed {}",
                self.unit,
                100.0 * done as f64 / total as f64,
                clock(elapsed)
            )
        } else {
            format!(
                "progress: {done} {}, {rate:.2}/s, elapsed {}",
                self.unit,
                clock(elapsed)
            )
        };
        let message = self.message.lock().expect("progress message");
        if !message.is_empty() {
            line.push_str(", ");
            line.push_str(&message);
        }
        line
    }
}

/// `1h02m03s`, `4m05s` or `7s`.
fn clock(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    match (s / 3600, s / 60 % 60, s % 60) {
        (0, 0, s) => format!("{s}s"),
        (0, m, s) => format!("{m}m{s:02}s"),
        (h, m, s) => format!("{h}h{m:02}m{s:02}s"),
    }
}

/// A terminal bar, or plain lines at an interval, or nothing (`-q`).
pub struct Progress {
    bar: ProgressBar,
    plain: Option<Plain>,
}

struct Plain {
    state: Arc<State>,
    stop: Option<Sender<()>>,
    timer: Option<JoinHandle<()>>,
}

impl Progress {
    /// `bar` on a terminal; `plain` = Some(interval) when stderr is not one.
    pub fn new(bar: ProgressBar, unit: &str, plain: Option<Duration>) -> Progress {
        let plain = plain.map(|interval| {
            let state = Arc::new(State {
                unit: unit.to_string(),
                total: AtomicU64::new(0),
                done: AtomicU64::new(0),
                message: Mutex::new(String::new()),
                started: Instant::now(),
            });
            let (stop, stopped) = bounded::<()>(1);
            let shared = Arc::clone(&state);
            let timer = std::thread::spawn(move || {
                while let Err(RecvTimeoutError::Timeout) = stopped.recv_timeout(interval) {
                    let mut err = std::io::stderr().lock();
                    let _ = writeln!(err, "{}", shared.line());
                }
                // The log ends with the final count, however short the run.
                if shared.done.load(Ordering::Relaxed) > 0 {
                    let _ = writeln!(std::io::stderr().lock(), "{}", shared.line());
                }
            });
            Plain {
                state,
                stop: Some(stop),
                timer: Some(timer),
            }
        });
        Progress { bar, plain }
    }

    pub fn set_length(&self, total: u64) {
        self.bar.set_length(total);
        if let Some(p) = &self.plain {
            p.state.total.store(total, Ordering::Relaxed);
        }
    }

    pub fn set_position(&self, done: u64) {
        self.bar.set_position(done);
        if let Some(p) = &self.plain {
            p.state.done.store(done, Ordering::Relaxed);
        }
    }

    pub fn inc(&self, by: u64) {
        self.bar.inc(by);
        if let Some(p) = &self.plain {
            p.state.done.fetch_add(by, Ordering::Relaxed);
        }
    }

    pub fn set_message(&self, message: String) {
        if let Some(p) = &self.plain {
            *p.state.message.lock().expect("progress message") = message.clone();
        }
        self.bar.set_message(message);
    }

    /// Removes the bar and stops the plain lines.
    pub fn finish_and_clear(&self) {
        self.bar.finish_and_clear();
        if let Some(p) = &self.plain {
            // a full channel means the stop was already sent
            if let Some(stop) = &p.stop {
                let _ = stop.try_send(());
            }
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if let Some(p) = &mut self.plain {
            drop(p.stop.take());
            if let Some(timer) = p.timer.take() {
                let _ = timer.join();
            }
        }
    }
}

/// The interval of the plain lines: `DSMSTREAM_PROGRESS_SECS`, or the default;
/// None when it is 0 (or not a number >= 0).
pub fn plain_interval() -> Option<Duration> {
    let seconds = match std::env::var("DSMSTREAM_PROGRESS_SECS") {
        Ok(text) => text.trim().parse::<f64>().ok()?,
        Err(_) => DEFAULT_INTERVAL_S,
    };
    (seconds.is_finite() && seconds > 0.0).then(|| Duration::from_secs_f64(seconds))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_lines_say_done_total_rate_eta_and_the_message() {
        let p = Progress::new(
            ProgressBar::hidden(),
            "pairs",
            Some(Duration::from_secs(3600)),
        );
        p.set_length(40);
        p.set_position(10);
        p.set_message("cache hit 50%".into());
        let line = p.plain.as_ref().unwrap().state.line();
        assert!(
            line.starts_with("progress: 10/40 pairs (25.0%), "),
            "{line}"
        );
        assert!(
            line.contains("/s, eta ") && line.ends_with(", cache hit 50%"),
            "{line}"
        );
        assert!(!line.contains('\u{1b}'), "no ANSI codes: {line}");
        p.finish_and_clear();
        assert_eq!(clock(3725.0), "1h02m05s");
        assert_eq!(clock(65.0), "1m05s");
        assert_eq!(clock(7.2), "7s");
    }
}
