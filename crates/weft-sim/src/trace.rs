//! Timeline tracing: spans per stage and per task, one track per thread —
//! weft's counterpart of the Projections timelines of the Charm++ paper.
//!
//! Off by default: a span then costs one relaxed atomic load. `weft run
//! --trace FILE` turns recording on (for chosen windows) and writes the spans
//! as Chrome-trace JSON ([`write_chrome_json`]), which Perfetto and
//! `chrome://tracing` open. The number of spans kept is capped, so a trace
//! stays bounded in size whatever the run; spans past the cap are counted.

use std::cell::Cell;
use std::io::Write;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::Instant;

/// One finished span.
#[derive(Clone, Copy, Debug)]
pub struct Span {
    pub name: &'static str,
    /// Track (thread) index, in order of first use.
    pub track: u32,
    /// Start and duration in nanoseconds since the recorder was created.
    pub start_ns: u64,
    pub dur_ns: u64,
    /// An optional argument (a window, partition or task size).
    pub arg: Option<(&'static str, u64)>,
}

struct Recorder {
    epoch: Instant,
    spans: Mutex<Vec<Span>>,
    tracks: Mutex<Vec<String>>,
    cap: AtomicU64,
    dropped: AtomicU64,
}

static RECORDING: AtomicBool = AtomicBool::new(false);
static NEXT_TRACK: AtomicU32 = AtomicU32::new(0);

thread_local! {
    static TRACK: Cell<Option<u32>> = const { Cell::new(None) };
}

fn recorder() -> &'static Recorder {
    static R: OnceLock<Recorder> = OnceLock::new();
    R.get_or_init(|| Recorder {
        epoch: Instant::now(),
        spans: Mutex::new(Vec::new()),
        tracks: Mutex::new(Vec::new()),
        cap: AtomicU64::new(DEFAULT_CAP),
        dropped: AtomicU64::new(0),
    })
}

/// Spans kept by default (about 110 bytes of JSON each: some 45 MB).
pub const DEFAULT_CAP: u64 = 400_000;

/// Sets how many spans are kept at most.
pub fn set_cap(cap: u64) {
    recorder().cap.store(cap, Ordering::Relaxed);
}

/// Turns recording on or off (spans open when it turns off are still kept).
pub fn set_recording(on: bool) {
    if on {
        recorder(); // fix the epoch before the first span
    }
    RECORDING.store(on, Ordering::Relaxed);
}

/// Whether spans are being recorded.
#[inline]
pub fn recording() -> bool {
    RECORDING.load(Ordering::Relaxed)
}

fn track() -> u32 {
    TRACK.with(|t| {
        if let Some(id) = t.get() {
            return id;
        }
        let id = NEXT_TRACK.fetch_add(1, Ordering::Relaxed);
        let name = std::thread::current()
            .name()
            .map_or_else(|| format!("thread {id}"), str::to_string);
        let mut tracks = recorder().tracks.lock().unwrap_or_else(|e| e.into_inner());
        if tracks.len() <= id as usize {
            tracks.resize(id as usize + 1, String::new());
        }
        tracks[id as usize] = name;
        t.set(Some(id));
        id
    })
}

/// An open span: recorded when dropped (if recording was on when it opened).
#[must_use = "a span measures until it is dropped"]
pub struct SpanGuard {
    open: Option<(&'static str, Instant, Option<Arg>)>,
}

/// A span's optional numeric argument: (name, value).
type Arg = (&'static str, u64);

/// Opens a span named `name` on the calling thread's track.
#[inline]
pub fn span(name: &'static str) -> SpanGuard {
    SpanGuard {
        open: recording().then(|| (name, Instant::now(), None)),
    }
}

/// Opens a span with one numeric argument.
#[inline]
pub fn span_with(name: &'static str, key: &'static str, value: u64) -> SpanGuard {
    SpanGuard {
        open: recording().then(|| (name, Instant::now(), Some((key, value)))),
    }
}

impl Drop for SpanGuard {
    fn drop(&mut self) {
        let Some((name, start, arg)) = self.open.take() else {
            return;
        };
        let r = recorder();
        let end = Instant::now();
        let span = Span {
            name,
            track: track(),
            start_ns: start.saturating_duration_since(r.epoch).as_nanos() as u64,
            dur_ns: end.saturating_duration_since(start).as_nanos() as u64,
            arg,
        };
        let mut spans = r.spans.lock().unwrap_or_else(|e| e.into_inner());
        if (spans.len() as u64) < r.cap.load(Ordering::Relaxed) {
            spans.push(span);
        } else {
            r.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

thread_local! {
    static SITE: Cell<&'static str> = const { Cell::new("") };
}

/// Names the collectives and exchanges the calling thread starts until the
/// guard drops (an inner site names them while it lives): a rank that
/// records its steps for `weft bench --project` tags each with it, so the
/// work before each collective, and the ranks' imbalance there, can be told
/// by where the run was. Always on: a thread-local store.
#[inline]
pub fn site(name: &'static str) -> SiteGuard {
    SiteGuard {
        outer: SITE.with(|s| s.replace(name)),
        _not_send: std::marker::PhantomData,
    }
}

/// A stage of the window under one name: its span in the trace and its
/// site for the counted collectives.
#[must_use = "the stage lasts while the guard lives"]
pub struct StageGuard {
    _span: SpanGuard,
    _site: SiteGuard,
}

/// Opens the stage `name`: a span (with an optional numeric argument) and
/// a site of that name.
#[inline]
pub fn stage(name: &'static str, arg: Option<(&'static str, u64)>) -> StageGuard {
    StageGuard {
        _span: SpanGuard {
            open: recording().then(|| (name, Instant::now(), arg)),
        },
        _site: site(name),
    }
}

/// The calling thread's innermost site ("" outside every site).
#[inline]
pub fn current_site() -> &'static str {
    SITE.with(Cell::get)
}

/// Restores the enclosing site when dropped ([`site`]).
#[must_use = "the site lasts while the guard lives"]
pub struct SiteGuard {
    outer: &'static str,
    _not_send: std::marker::PhantomData<*const ()>,
}

impl Drop for SiteGuard {
    fn drop(&mut self) {
        SITE.with(|s| s.set(self.outer));
    }
}

/// Takes the recorded spans (sorted by track, then start), the track names,
/// and the number of spans dropped over the cap; recording state is kept.
pub fn take() -> (Vec<Span>, Vec<String>, u64) {
    let r = recorder();
    let mut spans = std::mem::take(&mut *r.spans.lock().unwrap_or_else(|e| e.into_inner()));
    spans.sort_by_key(|s| (s.track, s.start_ns));
    let tracks = r.tracks.lock().unwrap_or_else(|e| e.into_inner()).clone();
    (spans, tracks, r.dropped.swap(0, Ordering::Relaxed))
}

/// Writes spans as Chrome-trace JSON (`ph: "X"` complete events, times in
/// microseconds) with one named track per thread under process `pid` (a rank).
pub fn write_chrome_json(
    out: &mut impl Write,
    pid: u32,
    process_name: &str,
    spans: &[Span],
    tracks: &[String],
    dropped: u64,
) -> std::io::Result<()> {
    let quote = |s: &str| serde_json::to_string(s).unwrap_or_else(|_| "\"?\"".into());
    writeln!(out, "{{\"displayTimeUnit\":\"ms\",\"traceEvents\":[")?;
    write!(
        out,
        "{{\"ph\":\"M\",\"name\":\"process_name\",\"pid\":{pid},\"tid\":0,\"args\":{{\"name\":{}}}}}",
        quote(process_name)
    )?;
    for (id, name) in tracks.iter().enumerate() {
        write!(
            out,
            ",\n{{\"ph\":\"M\",\"name\":\"thread_name\",\"pid\":{pid},\"tid\":{id},\"args\":{{\"name\":{}}}}}",
            quote(name)
        )?;
    }
    for s in spans {
        write!(
            out,
            ",\n{{\"ph\":\"X\",\"name\":\"{}\",\"pid\":{pid},\"tid\":{},\"ts\":{:.3},\"dur\":{:.3}",
            s.name,
            s.track,
            s.start_ns as f64 / 1e3,
            s.dur_ns as f64 / 1e3
        )?;
        match s.arg {
            Some((k, v)) => write!(out, ",\"args\":{{\"{k}\":{v}}}}}")?,
            None => write!(out, "}}")?,
        }
    }
    writeln!(
        out,
        "\n],\"otherData\":{{\"spans\":{},\"dropped_over_cap\":{dropped}}}}}",
        spans.len()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sites_nest_per_thread_and_restore_the_enclosing_one() {
        assert_eq!(current_site(), "");
        {
            let _stage = site("events");
            assert_eq!(current_site(), "events");
            {
                let _inner = site("events: velocities");
                assert_eq!(current_site(), "events: velocities");
                // Another thread has its own.
                std::thread::spawn(|| assert_eq!(current_site(), ""))
                    .join()
                    .unwrap();
            }
            assert_eq!(current_site(), "events");
        }
        assert_eq!(current_site(), "");
    }

    // One test touches the process-wide recorder (tests run in parallel).
    #[test]
    fn spans_record_only_while_on_are_capped_and_write_valid_json() {
        let _ = span("before");
        set_recording(true);
        set_cap(3);
        {
            let _a = span_with("window", "window", 7);
            // A stage: a span and a site of one name.
            let _b = stage("events", Some(("pass", 2)));
            assert_eq!(current_site(), "events");
        }
        assert_eq!(current_site(), "");
        std::thread::Builder::new()
            .name("worker".into())
            .spawn(|| drop(span("task")))
            .unwrap()
            .join()
            .unwrap();
        drop(span("over the cap"));
        set_recording(false);
        drop(span("after"));
        let (spans, tracks, dropped) = take();
        assert_eq!(spans.len(), 3);
        assert_eq!(dropped, 1);
        let names: Vec<_> = spans.iter().map(|s| s.name).collect();
        assert!(names.contains(&"window") && names.contains(&"task"));
        let events = spans.iter().find(|s| s.name == "events").unwrap();
        assert_eq!(events.arg, Some(("pass", 2)));
        assert!(tracks.iter().any(|t| t == "worker"));
        let mut buf = Vec::new();
        write_chrome_json(&mut buf, 0, "weft", &spans, &tracks, dropped).unwrap();
        let v: serde_json::Value = serde_json::from_slice(&buf).unwrap();
        let events = v["traceEvents"].as_array().unwrap();
        let window = events.iter().find(|e| e["name"] == "window").unwrap();
        assert_eq!(window["ph"], "X");
        assert_eq!(window["args"]["window"], 7);
        assert_eq!(v["otherData"]["dropped_over_cap"], 1);
        set_cap(DEFAULT_CAP);
    }
}
