//! Unwrapping the sensor's 24-bit millisecond counter (wraps every ~4 h 40 min).

const PERIOD: u64 = 1 << 24;

/// Turns successive 24-bit timestamps into a monotonic u64 millisecond count.
#[derive(Debug, Clone, Default)]
pub struct TimestampUnwrapper {
    last: Option<u64>,
}

impl TimestampUnwrapper {
    pub fn new() -> Self {
        Self::default()
    }

    /// A raw value more than half a period behind the last one is taken as a wrap; smaller
    /// steps back (reordered clock samples) stay in the current period.
    pub fn unwrap(&mut self, raw: u32) -> u64 {
        let raw = u64::from(raw) & (PERIOD - 1);
        let value = match self.last {
            None => raw,
            Some(last) => {
                let base = last & !(PERIOD - 1);
                let candidate = base + raw;
                if candidate + PERIOD / 2 < last {
                    candidate + PERIOD
                } else if candidate > last + PERIOD / 2 && base >= PERIOD {
                    candidate - PERIOD
                } else {
                    candidate
                }
            }
        };
        self.last = Some(self.last.map_or(value, |last| last.max(value)));
        value
    }

    /// Forget history (after `RS`, which restarts the sensor timer).
    pub fn reset(&mut self) {
        self.last = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wraps_once_per_period_and_tolerates_small_steps_back() {
        let mut u = TimestampUnwrapper::new();
        assert_eq!(u.unwrap(16_777_000), 16_777_000);
        assert_eq!(u.unwrap(100), PERIOD + 100);
        assert_eq!(u.unwrap(16_777_200), 16_777_200);
        assert_eq!(u.unwrap(200), PERIOD + 200);
        assert_eq!(u.unwrap(5_000), PERIOD + 5_000);
    }
}
