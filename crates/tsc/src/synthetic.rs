//! Generated two-agent interactions with known actions and phases, for tests,
//! examples and the `phasekit demo` command.
//!
//! [`generate`] makes handshake-like exchanges (the demo's data). [`generate_kind`]
//! makes any of four distinct interaction types ([`Kind`]: handshake, fist bump,
//! wave, handover), each with its own reach target and motion shape, so that a
//! library of interactions can be tested on data whose action and phases are known.
//!
//! Each demonstration has five phases: idle, reach, the action's own phase
//! (shake, bump, wave, hold), retract, rest. The human's hand (3-D) moves at
//! constant speed from rest to the action's target, performs the action's
//! motion there, returns and rests; the robot's hand does the same in its own
//! frame, a few frames later, towards a target that depends on where the human
//! reaches. Every phase starts with a change of the motion regime, so the
//! boundaries are observable from positions and velocities.
//! Durations, amplitudes and targets vary per demonstration; Gaussian noise
//! is added. The true phase of every frame is returned.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::f64::consts::PI;

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
    /// True phase of every frame (0 idle, 1 reach, 2 the action's own phase, 3 retract, 4 rest).
    pub phases: Vec<usize>,
    /// First frame of phases 1, 2, 3 and 4.
    pub boundaries: Vec<usize>,
}

/// The interaction types of [`generate_kind`]. Hand positions are in metres
/// from the hand's rest position (x forward towards the partner, y to the
/// side, z up).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    /// Reach forward to about (0.35, 0, 0.25), shake vertically (±4 cm, 2–3
    /// cycles), retract; exactly the demonstrations of [`generate`].
    Handshake,
    /// A quick reach to about (0.40, 0, 0.15), one forward jab of 5–7 cm (the
    /// bump), retract.
    FistBump,
    /// Raise the hand up and to the side, to about (0.12, −0.20, 0.45), wave
    /// sideways (±8 cm, 2–3 cycles), lower it; the robot waves back on its side.
    Wave,
    /// Reach low and to the side, to about (0.30, 0.10, 0.05), hold still while
    /// the object passes, retract.
    Handover,
}

impl Kind {
    /// Every kind, in a fixed order.
    pub const ALL: [Kind; 4] = [Kind::Handshake, Kind::FistBump, Kind::Wave, Kind::Handover];

    /// Its name, lower case (`handshake`, `fist-bump`, `wave`, `handover`).
    pub fn name(self) -> &'static str {
        match self {
            Kind::Handshake => "handshake",
            Kind::FistBump => "fist-bump",
            Kind::Wave => "wave",
            Kind::Handover => "handover",
        }
    }

    /// The name of the action phase (phase 2).
    pub fn action_phase(self) -> &'static str {
        match self {
            Kind::Handshake => "shake",
            Kind::FistBump => "bump",
            Kind::Wave => "wave",
            Kind::Handover => "hold",
        }
    }

    /// A seed offset so that each kind draws from its own random stream
    /// (the handshake's is 0: the stream of [`generate`]).
    fn stream(self) -> u64 {
        match self {
            Kind::Handshake => 0,
            Kind::FistBump => 0x9e37_79b9_7f4a_7c15,
            Kind::Wave => 0x3c6e_f372_fe94_f82a,
            Kind::Handover => 0xdaa6_6d2c_7ddf_743f,
        }
    }
}

/// What one demonstration draws: durations of the five phases, the robot's
/// lag, the human's target, the action's amplitude and cycles.
struct Draw {
    durations: [usize; 5],
    lag: usize,
    meet: [f64; 3],
    amp: f64,
    cycles: f64,
}

impl Draw {
    /// Draws one demonstration's parameters. The handshake's draws (their order
    /// and ranges) are those of the original generator, so [`generate`] keeps
    /// its output bit for bit.
    fn new(kind: Kind, rng: &mut ChaCha8Rng) -> Draw {
        // Phase durations (frames), target, amplitude centre and the scale of
        // its ±0.01 jitter, cycles of the action phase (fixed when lo = hi).
        type Spec = ([std::ops::Range<usize>; 5], [f64; 3], f64, f64, (f64, f64));
        let (d, target, amp, amp_scale, cycles): Spec = match kind {
            Kind::Handshake => (
                [10..20, 25..35, 40..60, 25..35, 10..20],
                [0.35, 0.0, 0.25],
                0.04,
                1.0,
                (2.0, 3.0),
            ),
            Kind::FistBump => (
                [10..20, 15..22, 10..16, 20..30, 10..20],
                [0.40, 0.0, 0.15],
                0.06,
                1.0,
                (1.0, 1.0),
            ),
            Kind::Wave => (
                [10..20, 25..35, 45..65, 25..35, 10..20],
                [0.12, -0.20, 0.45],
                0.08,
                2.0,
                (2.0, 3.0),
            ),
            Kind::Handover => (
                [10..20, 25..35, 20..35, 25..35, 10..20],
                [0.30, 0.10, 0.05],
                0.0,
                0.0,
                (1.0, 1.0),
            ),
        };
        let durations = d.map(|r| rng.random_range(r));
        let lag: usize = rng.random_range(2..5);
        let meet = [
            target[0] + rng.random_range(-0.04..0.04),
            // `0.0 + x` is `x` bit for bit (a sum of non-zero opposites is +0).
            target[1] + rng.random_range(-0.05..0.05),
            target[2] + rng.random_range(-0.04..0.04),
        ];
        let amp = amp + rng.random_range(-0.01..0.01) * amp_scale;
        let cycles = if cycles.0 < cycles.1 {
            rng.random_range(cycles.0..cycles.1)
        } else {
            cycles.0
        };
        Draw {
            durations,
            lag,
            meet,
            amp,
            cycles,
        }
    }
}

/// The robot's target for a human target `meet`: the same point seen from
/// the facing partner (handshake, fist bump, handover), or its own raised
/// hand (wave).
fn robot_target(kind: Kind, meet: [f64; 3]) -> [f64; 3] {
    match kind {
        Kind::Handshake => [meet[0] + 0.02, -meet[1], meet[2] - 0.01],
        Kind::FistBump => [meet[0] + 0.03, -meet[1], meet[2]],
        Kind::Wave => [meet[0] - 0.02, meet[1], meet[2] - 0.02],
        Kind::Handover => [meet[0] + 0.02, -meet[1], meet[2] + 0.02],
    }
}

/// Position along one phase at fraction `tau` of it.
fn hand(kind: Kind, phase: usize, tau: f64, meet: [f64; 3], amp: f64, cycles: f64) -> [f64; 3] {
    match phase {
        1 => meet.map(|m| m * tau),
        2 => match kind {
            Kind::Handshake => [
                meet[0],
                meet[1],
                meet[2] + amp * (2.0 * PI * cycles * tau).sin(),
            ],
            Kind::FistBump => [meet[0] + amp * (PI * tau).sin(), meet[1], meet[2]],
            Kind::Wave => [
                meet[0],
                meet[1] + amp * (2.0 * PI * cycles * tau).sin(),
                meet[2],
            ],
            Kind::Handover => meet,
        },
        3 => meet.map(|m| m * (1.0 - tau)),
        _ => [0.0, 0.0, 0.0],
    }
}

/// Generates `n` handshake-like demonstrations from `seed` (same seed, same
/// data): `generate_kind(Kind::Handshake, n, seed)`.
pub fn generate(n: usize, seed: u64) -> Vec<Interaction> {
    generate_kind(Kind::Handshake, n, seed)
}

/// Generates `n` demonstrations of `kind` from `seed` (same kind and seed,
/// same data; each kind draws from its own random stream).
pub fn generate_kind(kind: Kind, n: usize, seed: u64) -> Vec<Interaction> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ kind.stream());
    let noise = Normal::new(0.0, 0.004).expect("valid normal");
    (0..n)
        .map(|_| {
            let Draw {
                durations,
                lag,
                meet,
                amp,
                cycles,
            } = Draw::new(kind, &mut rng);
            let robot_meet = robot_target(kind, meet);
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
                let h = hand(kind, p, tau, meet, amp, cycles);
                let r = hand(kind, rp, rtau, robot_meet, amp, cycles);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// FNV-1a over the bits of every value, phase and boundary.
    fn fingerprint(demos: impl IntoIterator<Item = Interaction>) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for d in demos {
            let values = d.frames.iter().map(|v| v.to_bits());
            let labels = d.phases.iter().chain(&d.boundaries).map(|&p| p as u64);
            for v in values.chain(labels) {
                h ^= v;
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        }
        h
    }

    #[test]
    fn handshakes_are_those_of_the_original_generator_bit_for_bit() {
        // Taken from the generator before interaction types were added
        // (`generate(16, 0)`, `generate(5, 7)`, `generate(30, 121)`): the demo's
        // numbers and many tests depend on these exact frames.
        let all = [(16, 0), (5, 7), (30, 121)]
            .into_iter()
            .flat_map(|(n, s)| generate(n, s));
        assert_eq!(fingerprint(all), 0x12bc_971e_8f7c_6a0b);
    }

    #[test]
    fn every_kind_has_five_phases_in_order_and_reaches_its_target() {
        for kind in Kind::ALL {
            for d in generate_kind(kind, 6, 3) {
                let t = d.phases.len();
                assert_eq!(d.frames.len(), 6 * t);
                assert!(d
                    .phases
                    .windows(2)
                    .all(|w| w[1] == w[0] || w[1] == w[0] + 1));
                assert_eq!((d.phases[0], d.phases[t - 1]), (0, 4));
                assert_eq!(d.boundaries.len(), 4);
                for (p, &b) in d.boundaries.iter().enumerate() {
                    assert_eq!(d.phases[b], p + 1);
                    assert_eq!(d.phases[b - 1], p);
                }
                // Rest at the start and the end (noise σ = 4 mm).
                for &f in &[0, t - 1] {
                    assert!(d.frames[6 * f..6 * f + 3].iter().all(|v| v.abs() < 0.03));
                }
            }
        }
    }

    #[test]
    fn kinds_differ_where_the_hand_goes_and_how_it_moves_there() {
        // Mean human hand position during the action phase, per kind.
        let centre = |kind| {
            let demos = generate_kind(kind, 8, 1);
            let mut sum = [0.0; 3];
            let mut n = 0.0;
            for d in &demos {
                for (t, &p) in d.phases.iter().enumerate() {
                    if p == 2 {
                        (0..3).for_each(|k| sum[k] += d.frames[6 * t + k]);
                        n += 1.0;
                    }
                }
            }
            sum.map(|s| s / n)
        };
        let c: Vec<[f64; 3]> = Kind::ALL.iter().map(|&k| centre(k)).collect();
        for i in 0..4 {
            for j in 0..i {
                let dist = (0..3)
                    .map(|k| (c[i][k] - c[j][k]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                assert!(
                    dist > 0.09,
                    "{:?} and {:?} meet {dist} m apart",
                    Kind::ALL[i],
                    Kind::ALL[j]
                );
            }
        }
        // Same seed, same data; another kind, other data.
        assert_eq!(
            generate_kind(Kind::Wave, 3, 9),
            generate_kind(Kind::Wave, 3, 9)
        );
        assert_ne!(
            generate_kind(Kind::Wave, 3, 9)[0].frames[..6],
            generate_kind(Kind::Handover, 3, 9)[0].frames[..6]
        );
    }
}
