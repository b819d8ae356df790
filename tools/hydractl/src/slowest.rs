//! The N slowest of a stream of measurements, kept in a fixed array: the
//! benchmarks keep them while they measure, where nothing may allocate.

/// The `N` entries with the greatest keys seen, greatest first; empty
/// places hold key 0.
#[derive(Debug, Clone, Copy)]
pub struct Slowest<T: Copy + Default, const N: usize>([(u64, T); N]);

impl<T: Copy + Default, const N: usize> Default for Slowest<T, N> {
    fn default() -> Self {
        Self([(0, T::default()); N])
    }
}

impl<T: Copy + Default, const N: usize> Slowest<T, N> {
    /// Keeps `value` if `key` is among the `N` greatest so far.
    pub fn keep(&mut self, key: u64, value: T) {
        if let Some(rank) = self.0.iter().position(|(k, _)| key > *k) {
            self.0[rank..].rotate_right(1);
            self.0[rank] = (key, value);
        }
    }

    /// The kept entries, greatest first.
    pub fn iter(&self) -> impl Iterator<Item = &(u64, T)> {
        self.0.iter().filter(|(key, _)| *key > 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_greatest_greatest_first() {
        let mut slowest = Slowest::<char, 3>::default();
        for (key, value) in [(5, 'a'), (1, 'b'), (9, 'c'), (7, 'd'), (2, 'e')] {
            slowest.keep(key, value);
        }
        let kept: Vec<(u64, char)> = slowest.iter().copied().collect();
        assert_eq!(kept, [(9, 'c'), (7, 'd'), (5, 'a')]);
        assert_eq!(Slowest::<(), 2>::default().iter().count(), 0);
    }
}
