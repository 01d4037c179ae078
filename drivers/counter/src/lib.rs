//! Unwrapping a modular hardware counter (a sensor's 24-bit millisecond clock, an IMU's
//! SampleTimeFine) into a running count.
//!
//! Between two readings the counter is taken to have moved by the *shortest signed step*: a
//! forward step of at most half the modulus counts forward, a larger one counts as a step
//! back. Small steps back (reordered or GNSS-stamped samples) therefore stay steps back instead
//! of becoming a false wrap, and the result depends only on successive pairs of readings, never
//! on where the first one fell.

/// The counter's shortest signed step from `from` to `to`, both taken modulo `modulus`
/// (at least 1): in `-(modulus - 1) / 2 ..= modulus / 2`.
pub fn signed_step(modulus: u64, from: u64, to: u64) -> i64 {
    let modulus = modulus.max(1);
    let forward = (to % modulus + modulus - from % modulus) % modulus;
    if forward > modulus / 2 {
        -((modulus - forward) as i64)
    } else {
        forward as i64
    }
}

/// Successive raw readings of a counter modulo `modulus`, unwrapped into one running count.
///
/// ```
/// let mut u = wrapping_counter::Unwrapper::new(1000);
/// let got: Vec<i64> = [900, 950, 20, 10, 400].map(|r| u.unwrap(r)).to_vec();
/// assert_eq!(got, [900, 950, 1020, 1010, 1400]);
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Unwrapper {
    modulus: u64,
    last_raw: Option<u64>,
    total: i64,
}

impl Unwrapper {
    /// A counter that wraps at `modulus` (raised to 2, the smallest that can count anything;
    /// at most 2^63 so that every step fits an `i64`).
    pub fn new(modulus: u64) -> Self {
        Self {
            modulus: modulus.clamp(2, 1 << 63),
            last_raw: None,
            total: 0,
        }
    }

    pub fn modulus(&self) -> u64 {
        self.modulus
    }

    /// The running count at reading `raw`: `raw % modulus` for the first reading (so that a
    /// counter read from power-up counts from its own zero), then the previous count plus the
    /// [`signed_step`] since the previous reading. It can go below zero if the counter steps
    /// back past where it was first read.
    pub fn unwrap(&mut self, raw: u64) -> i64 {
        let raw = raw % self.modulus;
        self.total = match self.last_raw {
            None => raw as i64,
            Some(last) => self.total + signed_step(self.modulus, last, raw),
        };
        self.last_raw = Some(raw);
        self.total
    }

    /// Forgets every reading: the next one starts the count again.
    pub fn reset(&mut self) {
        self.last_raw = None;
        self.total = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn wraps_forward_and_keeps_small_steps_back() {
        let mut u = Unwrapper::new(1 << 24);
        let raw = [16_777_000, 100, 16_777_200, 200, 5_000];
        let got: Vec<i64> = raw.iter().map(|&r| u.unwrap(r)).collect();
        let period = 1i64 << 24;
        assert_eq!(
            got,
            [
                16_777_000,
                period + 100,
                16_777_200,
                period + 200,
                period + 5_000
            ]
        );
    }

    #[test]
    fn half_a_period_forward_counts_forward_and_just_more_counts_back() {
        assert_eq!(signed_step(1000, 0, 500), 500);
        assert_eq!(signed_step(1000, 0, 501), -499);
        assert_eq!(signed_step(1001, 0, 500), 500);
        assert_eq!(signed_step(1001, 0, 501), -500);
        assert_eq!(signed_step(1000, 999, 0), 1);
        assert_eq!(
            signed_step(1000, 2999, 1000),
            1,
            "readings are taken modulo"
        );
    }

    #[test]
    fn a_step_back_past_the_first_reading_goes_negative() {
        let mut u = Unwrapper::new(1000);
        assert_eq!(u.unwrap(10), 10);
        assert_eq!(u.unwrap(990), -10);
    }

    #[test]
    fn reset_starts_again_from_the_next_reading() {
        let mut u = Unwrapper::new(1000);
        u.unwrap(900);
        u.unwrap(100);
        u.reset();
        assert_eq!(u.unwrap(300), 300);
        assert_eq!(u.modulus(), 1000);
    }

    #[test]
    fn degenerate_moduli_are_raised_to_two() {
        assert_eq!(Unwrapper::new(0).modulus(), 2);
        assert_eq!(signed_step(0, 5, 7), 0);
        assert_eq!(Unwrapper::new(u64::MAX).modulus(), 1 << 63);
    }

    proptest! {
        /// Any walk whose true steps stay within half a period is recovered exactly, whatever
        /// the modulus and wherever the walk starts.
        #[test]
        fn recovers_every_walk_of_short_steps(
            modulus in 2u64..=(1 << 40),
            start in any::<u64>(),
            fractions in proptest::collection::vec(-1.0f64..=1.0, 0..200),
        ) {
            let half = (modulus / 2) as i64;
            let min_step = -(((modulus - 1) / 2) as i64);
            let mut u = Unwrapper::new(modulus);
            let first = (start % modulus) as i64;
            prop_assert_eq!(u.unwrap(start), first);
            let mut truth = first;
            for f in fractions {
                let step = ((f * half as f64) as i64).clamp(min_step, half);
                truth += step;
                let raw = truth.rem_euclid(modulus as i64) as u64;
                prop_assert_eq!(u.unwrap(raw), truth);
            }
        }

        #[test]
        fn signed_step_is_the_shortest_congruent_step(
            modulus in 1u64..=(1 << 62),
            from in any::<u64>(),
            to in any::<u64>(),
        ) {
            let step = signed_step(modulus, from, to);
            prop_assert!(step.unsigned_abs() <= modulus / 2);
            let m = i128::from(modulus);
            prop_assert_eq!(
                (i128::from(from) + i128::from(step)).rem_euclid(m),
                i128::from(to).rem_euclid(m)
            );
        }
    }
}
