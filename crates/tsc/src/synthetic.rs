//! A generated two-agent interaction with known phases (a handshake-like
//! exchange), for tests, examples and the `phasekit demo` command.
//!
//! Each demonstration has five phases: idle, reach, shake, retract, rest. The
//! human's hand (3-D) moves at constant speed from rest to a meeting point,
//! oscillates vertically while shaking, returns and rests; the robot's hand
//! does the same in its own frame, a few frames later, towards a meeting
//! point that depends on where the human reaches. Every phase starts with a
//! change of the motion regime, so the boundaries are observable from
//! positions and velocities.
//! Durations, amplitudes and the meeting point vary per demonstration;
//! Gaussian noise is added. The true phase of every frame is returned.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Column names of a generated demonstration.
pub const COLUMNS: [&str; 6] = [
    "p1_wrist_x",
    "p1_wrist_y",
    "p1_wrist_z",
    "p2_wrist_x",
    "p2_wrist_y",
    "p2_wrist_z",
];

/// One generated demonstration.
#[derive(Debug, Clone, PartialEq)]
pub struct Interaction {
    /// `T × 6` row-major: human hand xyz, robot hand xyz (metres).
    pub frames: Vec<f64>,
    /// True phase of every frame (0 idle, 1 reach, 2 shake, 3 retract, 4 rest).
    pub phases: Vec<usize>,
    /// First frame of phases 1, 2, 3 and 4.
    pub boundaries: Vec<usize>,
}

/// Position along one phase at fraction `tau` of it.
fn hand(phase: usize, tau: f64, meet: [f64; 3], amp: f64, cycles: f64) -> [f64; 3] {
    match phase {
        1 => meet.map(|m| m * tau),
        2 => [
            meet[0],
            meet[1],
            meet[2] + amp * (2.0 * std::f64::consts::PI * cycles * tau).sin(),
        ],
        3 => meet.map(|m| m * (1.0 - tau)),
        _ => [0.0, 0.0, 0.0],
    }
}

/// Generates `n` demonstrations from `seed` (same seed, same data).
pub fn generate(n: usize, seed: u64) -> Vec<Interaction> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.004).expect("valid normal");
    (0..n)
        .map(|_| {
            let durations = [
                rng.random_range(10..20),
                rng.random_range(25..35),
                rng.random_range(40..60),
                rng.random_range(25..35),
                rng.random_range(10..20),
            ];
            let lag: usize = rng.random_range(2..5);
            let meet = [
                0.35 + rng.random_range(-0.04..0.04),
                rng.random_range(-0.05..0.05),
                0.25 + rng.random_range(-0.04..0.04),
            ];
            // The robot meets the human's hand: same point seen from the facing partner.
            let robot_meet = [meet[0] + 0.02, -meet[1], meet[2] - 0.01];
            let amp = 0.04 + rng.random_range(-0.01..0.01);
            let cycles = rng.random_range(2.0..3.0);
            let total: usize = durations.iter().sum::<usize>();
            let mut starts = [0usize; 5];
            for p in 1..5 {
                starts[p] = starts[p - 1] + durations[p - 1];
            }
            let phase_at = |t: usize| -> (usize, f64) {
                let p = (0..5).rev().find(|&p| t >= starts[p]).unwrap_or(0);
                (p, (t - starts[p]) as f64 / durations[p] as f64)
            };
            let mut frames = Vec::with_capacity(total * 6);
            let mut phases = Vec::with_capacity(total);
            for t in 0..total {
                let (p, tau) = phase_at(t);
                let (rp, rtau) = phase_at(t.saturating_sub(lag));
                let h = hand(p, tau, meet, amp, cycles);
                let r = hand(rp, rtau, robot_meet, amp, cycles);
                frames.extend(h.iter().chain(&r).map(|v| v + noise.sample(&mut rng)));
                phases.push(p);
            }
            Interaction {
                frames,
                phases,
                boundaries: starts[1..].to_vec(),
            }
        })
        .collect()
}

/// Features as the seed paper builds them: human position, human velocity,
/// robot position, robot velocity (`v_t = x_t − x_{t−1}`, `v_0 = 0`), `T × 12`.
pub fn with_velocities(interaction: &Interaction) -> Vec<f64> {
    let f = &interaction.frames;
    let n = f.len() / 6;
    let mut out = Vec::with_capacity(n * 12);
    for t in 0..n {
        let p = t.saturating_sub(1);
        for side in [0, 3] {
            out.extend_from_slice(&f[t * 6 + side..t * 6 + side + 3]);
            out.extend((0..3).map(|k| f[t * 6 + side + k] - f[p * 6 + side + k]));
        }
    }
    out
}
