//! Host time, and the device clock put on it.
//!
//! * [`HostClock`]: where "now" comes from. [`MonotonicClock`] reads `CLOCK_MONOTONIC`
//!   on Linux, the clock V4L2 stamps camera buffers with, so frame and LED timestamps
//!   land on one time axis. [`VirtualClock`] is a clock that only moves when told, for
//!   deterministic tests and simulations.
//! * [`ClockSync`]: maps the device's microseconds to host microseconds from time-sync
//!   pings. Each ping gives a [`TimeSample`]: the device read its clock somewhere between
//!   the host's send and receive times, so the true line `host = a + b·device` passes
//!   through every ping's interval. Over a sliding window, the slope `b` (1 + drift) is
//!   the middle of the range of slopes consistent with all pings (found around a
//!   least-squares fit of the shortest round trips' midpoints), and `a` is the middle of
//!   the band of intercepts consistent with all pings at that slope. Unlike a midpoint fit this is not biased when
//!   the two directions of the link have different delays: the bound from below comes
//!   from the ping with the fastest request, the one from above from the ping with the
//!   fastest reply. Half the band's width is reported as the uncertainty: a hard bound
//!   on the mapping error (for the fitted drift), not a statistical guess.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// Microseconds on the host's clock (see [`HostClock`]).
pub type HostMicros = u64;

/// A source of host time that can also wait.
pub trait HostClock: Send + Sync + std::fmt::Debug {
    /// Now, µs.
    fn now_us(&self) -> HostMicros;
    /// Block until `t` (a virtual clock jumps there).
    fn sleep_until(&self, t: HostMicros);
    /// Whether time only moves when told (tests, simulations).
    fn is_virtual(&self) -> bool {
        false
    }
}

/// The system's monotonic clock: `CLOCK_MONOTONIC` on Linux (the V4L2 buffer timestamp
/// clock); elsewhere the time since this clock was created.
#[derive(Debug, Clone)]
pub struct MonotonicClock {
    #[cfg(not(target_os = "linux"))]
    origin: std::time::Instant,
}

impl MonotonicClock {
    /// The system clock.
    pub fn new() -> Self {
        Self {
            #[cfg(not(target_os = "linux"))]
            origin: std::time::Instant::now(),
        }
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

impl HostClock for MonotonicClock {
    #[cfg(target_os = "linux")]
    fn now_us(&self) -> HostMicros {
        let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
        t.tv_sec as u64 * 1_000_000 + t.tv_nsec as u64 / 1000
    }

    #[cfg(not(target_os = "linux"))]
    fn now_us(&self) -> HostMicros {
        self.origin.elapsed().as_micros() as u64
    }

    fn sleep_until(&self, t: HostMicros) {
        let now = self.now_us();
        if t > now {
            std::thread::sleep(Duration::from_micros(t - now));
        }
    }
}

/// A clock that moves only when told; clones share one time.
#[derive(Debug, Clone, Default)]
pub struct VirtualClock(Arc<AtomicU64>);

impl VirtualClock {
    /// A virtual clock at `t` µs.
    pub fn starting_at(t: HostMicros) -> Self {
        Self(Arc::new(AtomicU64::new(t)))
    }

    /// Move forward by `d` µs.
    pub fn advance(&self, d: u64) {
        self.0.fetch_add(d, Ordering::SeqCst);
    }
}

impl HostClock for VirtualClock {
    fn now_us(&self) -> HostMicros {
        self.0.load(Ordering::SeqCst)
    }

    fn sleep_until(&self, t: HostMicros) {
        self.0.fetch_max(t, Ordering::SeqCst);
    }

    fn is_virtual(&self) -> bool {
        true
    }
}

/// One time-sync ping: the device read `device_us` between `host_send_us` and
/// `host_recv_us`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeSample {
    /// Host time just before the request was sent.
    pub host_send_us: HostMicros,
    /// The device's clock in its reply.
    pub device_us: u64,
    /// Host time just after the reply arrived.
    pub host_recv_us: HostMicros,
}

impl TimeSample {
    /// Round-trip time, µs.
    pub fn rtt_us(&self) -> u64 {
        self.host_recv_us.saturating_sub(self.host_send_us)
    }

    fn midpoint(&self) -> f64 {
        (self.host_send_us as f64 + self.host_recv_us as f64) / 2.0
    }
}

/// Settings of [`ClockSync`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockSyncConfig {
    /// Samples older than this (host time) leave the window.
    pub window: Duration,
    /// Fraction of the window's pings, shortest round trip first, whose midpoints give
    /// the first guess of the drift.
    pub keep_fraction: f64,
    /// Drift is only fitted once the kept samples span this much device time; before,
    /// the slope is taken as 1 (no drift).
    pub min_drift_span: Duration,
    /// Samples with a round trip above this are discarded outright.
    pub max_rtt: Duration,
}

impl Default for ClockSyncConfig {
    fn default() -> Self {
        Self {
            window: Duration::from_secs(60),
            keep_fraction: 0.25,
            min_drift_span: Duration::from_secs(2),
            max_rtt: Duration::from_millis(50),
        }
    }
}

/// The fitted line `host = host_ref + slope·(device - device_ref)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockFit {
    /// Device time at the centre of the kept samples.
    pub device_ref: u64,
    /// Host time matching `device_ref`.
    pub host_ref: f64,
    /// Host µs per device µs (1 + drift).
    pub slope: f64,
    /// Half the width of the band of lines consistent with every ping, µs: the largest
    /// error the mapping can have near `device_ref` (for the fitted drift).
    pub uncertainty_us: f64,
    /// Pings in the window.
    pub samples: usize,
    /// Smallest round trip in the window, µs.
    pub min_rtt_us: u64,
}

impl ClockFit {
    /// Device time `d` on the host clock, µs (fractional).
    pub fn to_host(&self, d: u64) -> f64 {
        self.host_ref + self.slope * (d as f64 - self.device_ref as f64)
    }

    /// Host time `h` on the device clock, µs (fractional).
    pub fn to_device(&self, h: f64) -> f64 {
        self.device_ref as f64 + (h - self.host_ref) / self.slope
    }

    /// Device clock drift relative to the host, parts per million (positive: the
    /// device runs slow, so one device µs lasts longer on the host).
    pub fn drift_ppm(&self) -> f64 {
        (self.slope - 1.0) * 1e6
    }
}

/// Device-to-host clock mapping from time-sync pings (see the module documentation).
#[derive(Debug, Clone)]
pub struct ClockSync {
    config: ClockSyncConfig,
    window: VecDeque<TimeSample>,
    fit: Option<ClockFit>,
    resets: u32,
    rejected: u64,
}

impl ClockSync {
    /// An empty synchroniser.
    pub fn new(config: ClockSyncConfig) -> Self {
        Self {
            config,
            window: VecDeque::new(),
            fit: None,
            resets: 0,
            rejected: 0,
        }
    }

    /// The current fit, once there is one sample.
    pub fn fit(&self) -> Option<&ClockFit> {
        self.fit.as_ref()
    }

    /// Times the device clock went backwards (a device reboot) and the window restarted.
    pub fn resets(&self) -> u32 {
        self.resets
    }

    /// Samples discarded for a round trip above the limit or an inverted host interval.
    pub fn rejected(&self) -> u64 {
        self.rejected
    }

    /// Device time `d` on the host clock, once synchronised.
    pub fn to_host(&self, d: u64) -> Option<f64> {
        self.fit.map(|f| f.to_host(d))
    }

    /// Add a ping and refit. Returns whether the sample was used.
    pub fn add(&mut self, sample: TimeSample) -> bool {
        if sample.host_recv_us < sample.host_send_us
            || sample.rtt_us() > self.config.max_rtt.as_micros() as u64
        {
            self.rejected += 1;
            return false;
        }
        if self
            .window
            .back()
            .is_some_and(|last| sample.device_us < last.device_us)
        {
            self.window.clear();
            self.resets += 1;
        }
        self.window.push_back(sample);
        let horizon = sample
            .host_recv_us
            .saturating_sub(self.config.window.as_micros() as u64);
        while self
            .window
            .front()
            .is_some_and(|s| s.host_recv_us < horizon)
        {
            self.window.pop_front();
        }
        self.fit = self.refit();
        true
    }

    fn refit(&self) -> Option<ClockFit> {
        let samples: Vec<TimeSample> = self.window.iter().copied().collect();
        let min_rtt_us = samples.iter().map(TimeSample::rtt_us).min()?;
        let device_ref = (samples.iter().map(|s| s.device_us as u128).sum::<u128>()
            / samples.len() as u128) as u64;
        let first = samples.first()?.device_us;
        // The window is in device order (a step back resets it in `add`), so this does not
        // wrap; saturating all the same, as a device clock is input from outside.
        let span = samples.last()?.device_us.saturating_sub(first);
        let drift_fitted = span as f64 >= self.config.min_drift_span.as_micros() as f64;
        let slope = if drift_fitted {
            let guess = least_squares_slope(&samples, device_ref, self.config.keep_fraction);
            central_slope(&samples, device_ref, guess)
        } else {
            1.0
        };
        let env = envelope(&samples, device_ref, slope);
        Some(ClockFit {
            device_ref,
            host_ref: (env.lower + env.upper) / 2.0,
            slope,
            uncertainty_us: env.width().abs() / 2.0,
            samples: samples.len(),
            min_rtt_us,
        })
    }
}

/// With `host = a + slope·(d - d_ref)`, every ping bounds the intercept `a`:
/// `send - slope·x ≤ a ≤ recv - slope·x`. The tightest bounds over all pings.
#[derive(Debug, Clone, Copy)]
struct Envelope {
    lower: f64,
    upper: f64,
}

impl Envelope {
    /// Width of the feasible intercepts (negative when the pings contradict each other,
    /// e.g. with a wrong slope).
    fn width(&self) -> f64 {
        self.upper - self.lower
    }
}

fn envelope(samples: &[TimeSample], device_ref: u64, slope: f64) -> Envelope {
    let mut env = Envelope {
        lower: f64::NEG_INFINITY,
        upper: f64::INFINITY,
    };
    for s in samples {
        let x = slope * (s.device_us as f64 - device_ref as f64);
        env.lower = env.lower.max(s.host_send_us as f64 - x);
        env.upper = env.upper.min(s.host_recv_us as f64 - x);
    }
    env
}

/// The middle of the range of slopes consistent with every ping (where the width of the
/// feasible intercepts is ≥ 0), searched within ±200 ppm of `guess` (any crystal). The
/// width is concave in the slope (a minimum of lines minus a maximum of lines), so the
/// consistent slopes form one interval around the width's maximum. When the pings
/// contradict each other for every slope, the least contradictory slope.
fn central_slope(samples: &[TimeSample], device_ref: u64, guess: f64) -> f64 {
    const REACH: f64 = 200e-6;
    let width = |s: f64| envelope(samples, device_ref, s).width();
    let (mut lo, mut hi) = (guess - REACH, guess + REACH);
    for _ in 0..80 {
        let m1 = lo + (hi - lo) / 3.0;
        let m2 = hi - (hi - lo) / 3.0;
        if width(m1) < width(m2) {
            lo = m1;
        } else {
            hi = m2;
        }
    }
    let best = (lo + hi) / 2.0;
    if width(best) < 0.0 {
        return best;
    }
    // Bisect each edge of the consistent interval.
    let edge = |mut inside: f64, mut outside: f64| {
        if width(outside) >= 0.0 {
            return outside;
        }
        for _ in 0..60 {
            let mid = (inside + outside) / 2.0;
            if width(mid) >= 0.0 {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        inside
    };
    (edge(best, guess - REACH) + edge(best, guess + REACH)) / 2.0
}

/// Least-squares slope of the round-trip midpoints of the `keep_fraction` of pings with
/// the shortest round trips: the starting guess for the envelope search.
fn least_squares_slope(samples: &[TimeSample], device_ref: u64, keep_fraction: f64) -> f64 {
    let mut kept = samples.to_vec();
    kept.sort_by_key(TimeSample::rtt_us);
    kept.truncate(((kept.len() as f64 * keep_fraction).ceil() as usize).max(2));
    let n = kept.len() as f64;
    let xs: Vec<f64> = kept
        .iter()
        .map(|s| s.device_us as f64 - device_ref as f64)
        .collect();
    let x_mean = xs.iter().sum::<f64>() / n;
    let y_mean = kept.iter().map(TimeSample::midpoint).sum::<f64>() / n;
    let sxx: f64 = xs.iter().map(|x| (x - x_mean).powi(2)).sum();
    if sxx <= 0.0 {
        return 1.0;
    }
    xs.iter()
        .zip(&kept)
        .map(|(x, s)| (x - x_mean) * (s.midpoint() - y_mean))
        .sum::<f64>()
        / sxx
}

impl Default for ClockSync {
    fn default() -> Self {
        Self::new(ClockSyncConfig::default())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(send: u64, device: u64, recv: u64) -> TimeSample {
        TimeSample {
            host_send_us: send,
            device_us: device,
            host_recv_us: recv,
        }
    }

    #[test]
    fn symmetric_pings_give_the_exact_offset_and_drift() {
        // Device = (host - 1000) / 1.0001 exactly; replies read mid-way through the ping.
        let mut sync = ClockSync::default();
        for k in 0..40u64 {
            let mid = 1_000_000 + k * 250_000;
            let device = ((mid - 1000) as f64 / 1.0001).round() as u64;
            assert!(sync.add(sample(mid - 300, device, mid + 300)));
        }
        let fit = sync.fit().unwrap();
        assert!((fit.drift_ppm() - 100.0).abs() < 0.5, "{}", fit.drift_ppm());
        let d = 5_000_000;
        let truth = d as f64 * 1.0001 + 1000.0;
        assert!((fit.to_host(d) - truth).abs() < 1.0);
        assert!((fit.to_device(truth) - d as f64).abs() < 1.0);
    }

    #[test]
    fn queued_pings_are_left_out_of_the_fit() {
        let mut sync = ClockSync::default();
        for k in 0..20u64 {
            let mid = 1000 + k * 100_000;
            // Every other reply waited 20 ms in a queue after the device read its clock.
            let recv = if k % 2 == 0 { mid + 100 } else { mid + 20_000 };
            sync.add(sample(mid - 100, mid, recv));
        }
        let fit = sync.fit().unwrap();
        assert_eq!(fit.min_rtt_us, 200);
        assert!((fit.to_host(1_000_000) - 1_000_000.0).abs() < 1.0);
    }

    #[test]
    fn a_device_reboot_restarts_the_window_and_bad_samples_are_refused() {
        let mut sync = ClockSync::default();
        sync.add(sample(1000, 50_000_000, 1200));
        sync.add(sample(2000, 50_001_000, 2200));
        assert!(!sync.add(sample(3000, 10, 2000)), "inverted interval");
        assert!(
            !sync.add(sample(3000, 10, 3000 + 60_000)),
            "round trip too long"
        );
        assert_eq!(sync.rejected(), 2);
        assert!(sync.add(sample(4000, 10, 4200)));
        assert_eq!(sync.resets(), 1);
        let fit = sync.fit().unwrap();
        assert_eq!(fit.samples, 1);
        assert!((fit.to_host(10) - 4100.0).abs() < 1e-9);
        assert!((fit.uncertainty_us - 100.0).abs() < 1e-9);
    }

    #[test]
    fn old_samples_leave_the_window() {
        let mut sync = ClockSync::new(ClockSyncConfig {
            window: Duration::from_secs(1),
            ..ClockSyncConfig::default()
        });
        // A first regime with the device 10 ms ahead, then one with it 10 ms behind.
        for k in 0..10u64 {
            let h = k * 100_000;
            sync.add(sample(h, h + 10_000, h));
        }
        for k in 10..40u64 {
            let h = k * 100_000;
            sync.add(sample(h, h - 10_000, h));
        }
        let fit = sync.fit().unwrap();
        assert!((fit.to_host(3_000_000) - 3_010_000.0).abs() < 1.0);
    }

    #[test]
    fn virtual_clock_moves_only_when_told() {
        let clock = VirtualClock::starting_at(5);
        let other = clock.clone();
        clock.advance(10);
        other.sleep_until(12);
        other.sleep_until(3);
        assert_eq!(clock.now_us(), 15);
        assert!(clock.is_virtual());
        let real = MonotonicClock::new();
        let a = real.now_us();
        real.sleep_until(a + 2000);
        assert!(real.now_us() >= a + 2000);
    }
}
