//! The blocks of particles whose per-particle state a CPU stepper may have written since its
//! last checkpoint, so that a checkpoint (every batch of `Simulation::advance`, every batch of
//! a haptic session) and a restore copy those blocks instead of every particle.
//!
//! Between two activations the chain writes only its force set (follow: displacements and
//! blend clocks; integration: the dynamic particles, a subset), so a checkpoint marks the force
//! set it leaves; an activation marks the candidates its mode machine visits and the force set
//! it makes (the set bits go on the stress and force sets' neighbours, which are in it), or
//! everything when it visits every particle. The stepper copies the marked blocks of every
//! per-particle state array (displacements, velocities, offsets, modes, blend clocks).

use std::ops::Range;

/// Particles per block: one bit of [`Touched`] each.
pub const TOUCH_BLOCK: usize = 64;

/// A bit per block of [`TOUCH_BLOCK`] particles, or everything.
#[derive(Clone, Debug)]
pub struct Touched {
    /// Bit b of word b / 64: block b may have been written.
    words: Vec<u64>,
    /// Every particle may have been written.
    all: bool,
    /// Number of particles.
    n: usize,
}

impl Touched {
    /// Nothing written yet among `n` particles.
    pub fn new(n: usize) -> Touched {
        Touched {
            words: vec![0; n.div_ceil(TOUCH_BLOCK).div_ceil(64)],
            all: false,
            n,
        }
    }

    /// Every particle may have been written.
    pub fn mark_all(&mut self) {
        self.all = true;
    }

    /// Whether every particle is marked.
    pub fn all(&self) -> bool {
        self.all
    }

    /// Mark the blocks of `particles` (indices below the particle count).
    pub fn mark(&mut self, particles: &[u32]) {
        if self.all {
            return;
        }
        for &p in particles {
            let b = p as usize / TOUCH_BLOCK;
            self.words[b / 64] |= 1 << (b % 64);
        }
    }

    /// Forget every mark, then mark `particles`.
    pub fn reset_to(&mut self, particles: &[u32]) {
        self.all = false;
        self.words.iter_mut().for_each(|w| *w = 0);
        self.mark(particles);
    }

    /// The particle ranges of the marked blocks, ascending (one range of every particle when
    /// all are marked).
    pub fn ranges(&self) -> Vec<Range<usize>> {
        if self.all {
            return std::iter::once(0..self.n).collect();
        }
        let mut out: Vec<Range<usize>> = Vec::new();
        for (w, &word) in self.words.iter().enumerate() {
            let mut bits = word;
            while bits != 0 {
                let b = 64 * w + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let r = b * TOUCH_BLOCK..((b + 1) * TOUCH_BLOCK).min(self.n);
                match out.last_mut() {
                    Some(last) if last.end == r.start => last.end = r.end,
                    _ => out.push(r),
                }
            }
        }
        out
    }
}

/// Copy the entries of the particles in `ranges` ([`Touched::ranges`]) of a per-particle
/// array of `width` values each from `src` into `dst` (both of `width` × the particle count).
pub fn copy_ranges<T: Copy>(ranges: &[Range<usize>], width: usize, src: &[T], dst: &mut [T]) {
    for r in ranges {
        let (a, b) = (width * r.start, width * r.end);
        dst[a..b].copy_from_slice(&src[a..b]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marked_blocks_become_merged_ascending_ranges() {
        let mut t = Touched::new(200);
        assert!(t.ranges().is_empty());
        t.mark(&[130, 5, 70, 199]);
        // Blocks 0, 1, 2 and 3 (the last one short): one merged range.
        assert_eq!(t.ranges(), std::iter::once(0..200).collect::<Vec<_>>());
        t.reset_to(&[5, 199]);
        assert_eq!(t.ranges(), vec![0..64, 192..200]);
        let src: Vec<u32> = (0..400).collect();
        let mut dst = vec![0u32; 400];
        copy_ranges(&t.ranges(), 2, &src, &mut dst);
        assert_eq!(&dst[..128], &src[..128]);
        assert!(dst[128..384].iter().all(|&x| x == 0));
        assert_eq!(&dst[384..], &src[384..]);
        t.mark_all();
        t.mark(&[3]);
        assert!(t.all());
        assert_eq!(t.ranges(), std::iter::once(0..200).collect::<Vec<_>>());
        t.reset_to(&[]);
        assert!(!t.all() && t.ranges().is_empty());
    }
}
