//! Per-client rate limits: a token bucket for each API key identity (or each peer address
//! when no keys are configured), `rate` tokens a second up to `burst`, one per request.
//! Memory stays bounded: a bucket that has refilled is the same as no bucket and is
//! forgotten, and past `MAX_BUCKETS` the least recently used ones make room.
//! The clock is a parameter (`check_at`), so the tests drive time by hand.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Clients remembered at most; beyond, those seen longest ago are dropped (they start again
/// with a full bucket, which errs on the side of serving).
const MAX_BUCKETS: usize = 100_000;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateSpec {
    /// Tokens per second.
    pub rate: f64,
    /// Bucket size: requests allowed at once after being idle.
    pub burst: u32,
}

impl RateSpec {
    /// `RATE[/s|/m|/h]` (requests per second, minute or hour; per second when no unit) and
    /// a burst (default: the per-second rate rounded up, at least 1).
    pub fn parse(rate: &str, burst: Option<u32>) -> Result<Self, String> {
        let bad = || format!("rate limit {rate:?}: expected a number of requests per second, minute or hour, like 20, 20/s, 300/m or 1000/h");
        let (n, per) = match rate.trim().split_once('/') {
            None => (rate.trim(), 1.0),
            Some((n, unit)) => (
                n.trim(),
                match unit.trim() {
                    "s" | "sec" => 1.0,
                    "m" | "min" => 60.0,
                    "h" | "hour" => 3600.0,
                    _ => return Err(bad()),
                },
            ),
        };
        let n: f64 = n.parse().map_err(|_| bad())?;
        if !n.is_finite() || n <= 0.0 {
            return Err(bad());
        }
        let rate = n / per;
        let burst = burst.unwrap_or(rate.ceil().max(1.0) as u32);
        if burst == 0 {
            return Err("rate_burst must be at least 1".into());
        }
        Ok(Self { rate, burst })
    }
}

struct Bucket {
    tokens: f64,
    at: Instant,
}

pub struct RateLimiter {
    spec: RateSpec,
    buckets: Mutex<HashMap<String, Bucket>>,
}

/// The client a bucket belongs to when there are no keys: its address, an IPv6 one by its
/// /64 (one host usually holds a whole /64, so single addresses would not limit it).
pub fn peer_client(ip: IpAddr) -> String {
    match ip {
        IpAddr::V4(v4) => format!("ip:{v4}"),
        IpAddr::V6(v6) => match v6.to_ipv4_mapped() {
            Some(v4) => format!("ip:{v4}"),
            None => {
                let s = v6.segments();
                format!("ip:{:x}:{:x}:{:x}:{:x}::/64", s[0], s[1], s[2], s[3])
            }
        },
    }
}

impl RateLimiter {
    pub fn new(spec: RateSpec) -> Self {
        Self { spec, buckets: Mutex::new(HashMap::new()) }
    }

    pub fn spec(&self) -> RateSpec {
        self.spec
    }

    pub fn check(&self, client: &str) -> Result<(), Duration> {
        self.check_at(client, Instant::now())
    }

    /// Takes a token of `client`'s bucket at `now`, or says how long until one is there.
    pub fn check_at(&self, client: &str, now: Instant) -> Result<(), Duration> {
        let RateSpec { rate, burst } = self.spec;
        let burst = burst as f64;
        let mut buckets = self.buckets.lock().expect("rate limiter lock");
        if !buckets.contains_key(client) && buckets.len() >= MAX_BUCKETS {
            Self::make_room(&mut buckets, rate, burst, now);
        }
        let b = buckets.entry(client.to_string()).or_insert(Bucket { tokens: burst, at: now });
        b.tokens = (b.tokens + now.saturating_duration_since(b.at).as_secs_f64() * rate).min(burst);
        b.at = now.max(b.at);
        if b.tokens >= 1.0 {
            b.tokens -= 1.0;
            Ok(())
        } else {
            Err(Duration::from_secs_f64((1.0 - b.tokens) / rate))
        }
    }

    /// Forgets the buckets that have refilled; if that frees nothing, the eighth seen
    /// longest ago (a batch, so that a flood of new clients does not scan the map each time).
    fn make_room(buckets: &mut HashMap<String, Bucket>, rate: f64, burst: f64, now: Instant) {
        buckets.retain(|_, b| b.tokens + now.saturating_duration_since(b.at).as_secs_f64() * rate < burst);
        if buckets.len() >= MAX_BUCKETS {
            let mut seen: Vec<Instant> = buckets.values().map(|b| b.at).collect();
            let cut = seen.len() / 8;
            let (_, oldest_kept, _) = seen.select_nth_unstable(cut);
            let oldest_kept = *oldest_kept;
            buckets.retain(|_, b| b.at >= oldest_kept);
        }
    }

    /// Forgets every bucket that has refilled (the server calls it now and then, so idle
    /// clients do not stay in memory until the map is full).
    pub fn forget_idle(&self, now: Instant) {
        let RateSpec { rate, burst } = self.spec;
        self.buckets.lock().expect("rate limiter lock").retain(|_, b| b.tokens + now.saturating_duration_since(b.at).as_secs_f64() * rate < burst as f64);
    }

    pub fn clients(&self) -> usize {
        self.buckets.lock().expect("rate limiter lock").len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_rates() {
        assert_eq!(RateSpec::parse("20", None).unwrap(), RateSpec { rate: 20.0, burst: 20 });
        assert_eq!(RateSpec::parse("20/s", Some(5)).unwrap(), RateSpec { rate: 20.0, burst: 5 });
        assert_eq!(RateSpec::parse("300/m", None).unwrap(), RateSpec { rate: 5.0, burst: 5 });
        assert_eq!(RateSpec::parse(" 0.5 ", None).unwrap(), RateSpec { rate: 0.5, burst: 1 });
        assert!((RateSpec::parse("36/h", None).unwrap().rate - 0.01).abs() < 1e-12);
        for bad in ["", "fast", "0", "-3/s", "10/d", "NaN", "inf", "10/"] {
            assert!(RateSpec::parse(bad, None).unwrap_err().contains("rate limit"), "{bad}");
        }
        assert!(RateSpec::parse("10", Some(0)).unwrap_err().contains("rate_burst"));
    }

    #[test]
    fn bucket_allows_the_burst_then_the_rate() {
        let l = RateLimiter::new(RateSpec { rate: 2.0, burst: 3 });
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        for _ in 0..3 {
            assert!(l.check_at("a", at(0)).is_ok());
        }
        assert_eq!(l.check_at("a", at(0)), Err(Duration::from_millis(500)));
        // Another client has its own bucket.
        assert!(l.check_at("b", at(0)).is_ok());
        // Half a token after 250 ms: still refused, for the other 250 ms.
        assert_eq!(l.check_at("a", at(250)), Err(Duration::from_millis(250)));
        assert!(l.check_at("a", at(500)).is_ok());
        assert!(l.check_at("a", at(500)).is_err());
        // Idle long enough, the bucket is full again but never more than the burst.
        for _ in 0..3 {
            assert!(l.check_at("a", at(60_000)).is_ok());
        }
        assert!(l.check_at("a", at(60_000)).is_err());
        // A clock that goes backwards (another thread's earlier `now`) adds nothing.
        assert!(l.check_at("a", at(59_000)).is_err());
    }

    #[test]
    fn idle_clients_are_forgotten_and_memory_is_bounded() {
        let l = RateLimiter::new(RateSpec { rate: 1.0, burst: 2 });
        let t0 = Instant::now();
        l.check_at("a", t0).unwrap();
        l.check_at("b", t0).unwrap();
        l.forget_idle(t0 + Duration::from_millis(500));
        assert_eq!(l.clients(), 2);
        l.forget_idle(t0 + Duration::from_secs(1));
        assert_eq!(l.clients(), 0);
        // Full of busy clients: the least recently seen one makes room.
        let l = RateLimiter::new(RateSpec { rate: 0.001, burst: 1 });
        for i in 0..MAX_BUCKETS {
            l.check_at(&format!("c{i}"), t0 + Duration::from_micros(i as u64)).unwrap();
        }
        l.check_at("new", t0 + Duration::from_secs(1)).unwrap();
        assert_eq!(l.clients(), MAX_BUCKETS - MAX_BUCKETS / 8 + 1);
        // The oldest eighth was dropped, so c0 starts again with a full bucket; the newest
        // are still empty.
        assert!(l.check_at("c0", t0 + Duration::from_secs(1)).is_ok());
        assert!(l.check_at(&format!("c{}", MAX_BUCKETS - 1), t0 + Duration::from_secs(1)).is_err());
    }

    #[test]
    fn peers_by_address_and_ipv6_by_64() {
        assert_eq!(peer_client("10.0.0.7".parse().unwrap()), "ip:10.0.0.7");
        assert_eq!(peer_client("::ffff:10.0.0.7".parse().unwrap()), "ip:10.0.0.7");
        assert_eq!(peer_client("2001:db8:1:2:aaaa::1".parse().unwrap()), peer_client("2001:db8:1:2::9".parse().unwrap()));
        assert_eq!(peer_client("2001:db8:1:2::9".parse().unwrap()), "ip:2001:db8:1:2::/64");
    }
}
