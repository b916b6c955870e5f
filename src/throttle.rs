//! Login throttling: failed logins slow down guessing, per account *from one client address*
//! and per client address, with exponential back-off.
//!
//! * After [`Policy::pair_free`] failures for one account from one address, each further failure
//!   blocks that pair for `base * 2^k` (capped at [`Policy::max_block`]); while blocked, every
//!   attempt of the pair, right or wrong, is refused with the time left (HTTP 429 +
//!   `Retry-After`), so guessing gets no answer.
//! * The same per address over all accounts, with a larger allowance ([`Policy::address_free`]),
//!   against spraying one password over many accounts.
//! * Nothing is keyed by the account alone: an attacker elsewhere cannot lock the real user
//!   out; the right password from another address still works.
//! * A successful login clears its pair's record. Records are forgotten after
//!   [`Policy::forget_after`] without failures, and the table is bounded
//!   ([`Policy::max_entries`]), oldest records dropped first.
//!
//! State is in memory (one server process), like the sessions' throttling in most servers: a
//! restart forgives, which an attacker cannot cause.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Throttling parameters.
#[derive(Debug, Clone)]
pub struct Policy {
    /// Failures of one account from one address before back-off starts.
    pub pair_free: u32,
    /// Failures from one address (any account) before back-off starts.
    pub address_free: u32,
    /// First block.
    pub base: Duration,
    /// Longest block.
    pub max_block: Duration,
    /// A record without failures for this long is forgotten.
    pub forget_after: Duration,
    /// Most records kept.
    pub max_entries: usize,
}

impl Default for Policy {
    fn default() -> Self {
        Policy {
            pair_free: 5,
            address_free: 50,
            base: Duration::from_secs(5),
            max_block: Duration::from_secs(15 * 60),
            forget_after: Duration::from_secs(24 * 3600),
            max_entries: 100_000,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum Key {
    Pair(String, IpAddr),
    Address(IpAddr),
}

#[derive(Debug, Clone, Copy)]
struct Record {
    failures: u32,
    blocked_until: Option<Instant>,
    last_failure: Instant,
}

/// Failed-login records; cheap to clone (shared).
#[derive(Debug, Clone, Default)]
pub struct LoginThrottle {
    policy: Arc<Policy>,
    records: Arc<Mutex<HashMap<Key, Record>>>,
}

/// The outcome of a failure: how many in a row, and for how long the pair is now blocked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Failure {
    /// Failures of this account from this address in a row.
    pub pair_failures: u32,
    /// Failures from this address.
    pub address_failures: u32,
    /// Block now in force for the pair or the address (the longer), if any.
    pub blocked_for: Option<Duration>,
}

impl LoginThrottle {
    /// A throttle with `policy`.
    pub fn new(policy: Policy) -> LoginThrottle {
        LoginThrottle {
            policy: Arc::new(policy),
            records: Arc::default(),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<Key, Record>> {
        self.records.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn keys(username: &str, addr: IpAddr) -> [Key; 2] {
        [Key::Pair(username.to_lowercase(), addr), Key::Address(addr)]
    }

    /// `Err(time left)` while `username` from `addr` is blocked; check before verifying the
    /// password.
    pub fn check(&self, username: &str, addr: IpAddr, now: Instant) -> Result<(), Duration> {
        let records = self.lock();
        let left = Self::keys(username, addr)
            .iter()
            .filter_map(|k| records.get(k)?.blocked_until)
            .filter(|&until| until > now)
            .map(|until| until - now)
            .max();
        match left {
            Some(d) => Err(d),
            None => Ok(()),
        }
    }

    /// Records a failed login of `username` from `addr`.
    pub fn failed(&self, username: &str, addr: IpAddr, now: Instant) -> Failure {
        let p = &*self.policy;
        let mut records = self.lock();
        if records.len() >= p.max_entries {
            self.prune(&mut records, now);
        }
        let mut counts = [0u32; 2];
        let mut blocked: Option<Duration> = None;
        for (i, key) in Self::keys(username, addr).into_iter().enumerate() {
            let free = match key {
                Key::Pair(..) => p.pair_free,
                Key::Address(_) => p.address_free,
            };
            let r = records.entry(key).or_insert(Record {
                failures: 0,
                blocked_until: None,
                last_failure: now,
            });
            r.failures = r.failures.saturating_add(1);
            r.last_failure = now;
            if r.failures > free {
                let k = (r.failures - free - 1).min(30);
                let block = p.base.saturating_mul(1u32 << k).min(p.max_block);
                r.blocked_until = Some(now + block);
                blocked = Some(blocked.map_or(block, |b| b.max(block)));
            }
            counts[i] = r.failures;
        }
        Failure {
            pair_failures: counts[0],
            address_failures: counts[1],
            blocked_for: blocked,
        }
    }

    /// Records a successful login: the pair's failures are forgiven (the address's are not:
    /// one valid account must not whitewash guessing at others).
    pub fn succeeded(&self, username: &str, addr: IpAddr) {
        let [pair, _] = Self::keys(username, addr);
        self.lock().remove(&pair);
    }

    fn prune(&self, records: &mut HashMap<Key, Record>, now: Instant) {
        let forget = self.policy.forget_after;
        records.retain(|_, r| {
            now.duration_since(r.last_failure) < forget || r.blocked_until.is_some_and(|u| u > now)
        });
        // Still full: drop the oldest half.
        if records.len() >= self.policy.max_entries {
            let mut ages: Vec<Instant> = records.values().map(|r| r.last_failure).collect();
            ages.sort_unstable();
            let cut = ages[ages.len() / 2];
            records.retain(|_, r| r.last_failure > cut);
        }
    }

    /// Records kept (for tests and metrics).
    pub fn len(&self) -> usize {
        self.lock().len()
    }

    /// Whether no record is kept.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ip(s: &str) -> IpAddr {
        s.parse().expect("ip")
    }

    #[test]
    fn back_off_per_pair_and_address_never_per_account() {
        let t = LoginThrottle::default();
        let (attacker, user) = (ip("10.0.0.1"), ip("10.0.0.2"));
        let now = Instant::now();
        for _ in 0..5 {
            assert_eq!(t.check("Alice", attacker, now), Ok(()));
            assert_eq!(t.failed("alice", attacker, now).blocked_for, None);
        }
        // The sixth failure blocks for 5 s, the seventh for 10 s, ...
        assert_eq!(
            t.failed("alice", attacker, now).blocked_for,
            Some(Duration::from_secs(5))
        );
        assert!(t.check("alice", attacker, now).is_err());
        assert!(t.check("ALICE", attacker, now).is_err(), "names fold case");
        assert!(
            t.check("alice", attacker, now + Duration::from_secs(4))
                .is_err()
        );
        let later = now + Duration::from_secs(5);
        assert_eq!(t.check("alice", attacker, later), Ok(()));
        assert_eq!(
            t.failed("alice", attacker, later).blocked_for,
            Some(Duration::from_secs(10))
        );
        // The real user elsewhere is not blocked, and other accounts from the attacker's
        // address are not blocked before the address allowance is spent.
        assert_eq!(t.check("alice", user, later), Ok(()));
        assert_eq!(t.check("bob", attacker, later), Ok(()));
        // The block is capped.
        let mut at = later;
        let mut last = None;
        for _ in 0..40 {
            at += Duration::from_secs(16 * 60);
            last = t.failed("alice", attacker, at).blocked_for;
        }
        assert_eq!(last, Some(Policy::default().max_block));
        // A success forgives the pair.
        t.succeeded("alice", user);
        t.succeeded("alice", attacker);
        assert_eq!(t.check("alice", attacker, at), Ok(()));
    }

    #[test]
    fn spraying_from_one_address_is_throttled() {
        let t = LoginThrottle::default();
        let a = ip("::1");
        let now = Instant::now();
        let mut first_block = None;
        for k in 0..60u32 {
            let f = t.failed(&format!("user{k}"), a, now);
            if f.blocked_for.is_some() && first_block.is_none() {
                first_block = Some(k + 1);
            }
        }
        assert_eq!(first_block, Some(Policy::default().address_free + 1));
        assert!(t.check("someone-else", a, now).is_err());
        assert_eq!(t.check("someone-else", ip("::2"), now), Ok(()));
    }

    #[test]
    fn the_table_stays_bounded() {
        let t = LoginThrottle::new(Policy {
            max_entries: 100,
            ..Policy::default()
        });
        let now = Instant::now();
        for k in 0..1000u32 {
            let addr = IpAddr::from([10, 0, (k >> 8) as u8, k as u8]);
            t.failed("alice", addr, now + Duration::from_millis(k as u64));
        }
        assert!(t.len() <= 100, "{} records", t.len());
    }
}
