//! What the autopilot is told, judged against truth: the ODOMETRY stream (body velocity, its
//! covariance, quality and reset counter) the fusion sends at 30 Hz, on runs that start in
//! motion, lose their sensors, or fly where the surfaces leave an axis unobserved
//! (docs/autopilot.md). The short runs are real tests; the 20-run studies are `#[ignore]`d,
//! release-mode runs: `cargo test --release --test honest_velocity -- --ignored --nocapture`,
//! at 1 Hz epochs unless `HONEST_EPOCH_RATE_HZ` names another rate for every trial.

use ladar_odometer::daemon::mavlink_out::QualityPolicy;
use ladar_odometer::fusion::{Fusion, FusionSettings};
use ladar_odometer::odometry::OdometryMethod;
use ladar_sim::{Scenario, SimEvent, Simulator};
use nalgebra::Vector3;

const MESSAGE_RATE_HZ: f64 = 30.0;

/// Share of valid messages that must lie within 3 reported sigmas, per body axis.
const INSIDE_3_SIGMA: f64 = 0.97;
/// Largest mean normalised error squared per body axis (1 if honest).
const MEAN_NEES: f64 = 1.5;
/// Largest step of the reported position between messages without a reset, beyond what the
/// reported velocity explains, m.
const STEP_M: f64 = 0.2;

/// Sensors silent over `[from_s, to_s)`: the scanners, or everything (an emulator killed).
#[derive(Debug, Clone, Copy)]
struct Outage {
    from_s: f64,
    to_s: f64,
    imu_too: bool,
}

impl Outage {
    fn silences(&self, t: f64, imu: bool) -> bool {
        (self.from_s..self.to_s).contains(&t) && (self.imu_too || !imu)
    }
}

#[derive(Debug, Clone)]
struct Trial {
    scenario: Scenario,
    seed: u64,
    /// Nothing before this time reaches the fusion: the daemon starts here.
    start_s: f64,
    outage: Option<Outage>,
    method: OdometryMethod,
    epoch_rate_hz: f64,
    /// The ranging sigmas the fusion is told, where the scanners range worse than that.
    told_range_sigma_m: Option<[f64; 2]>,
}

impl Trial {
    fn new(name: &str, seed: u64, start_s: f64) -> Self {
        Self {
            scenario: Scenario::builtin(name).unwrap(),
            seed,
            start_s,
            outage: None,
            method: OdometryMethod::Pairs,
            epoch_rate_hz: 1.0,
            told_range_sigma_m: None,
        }
    }

    /// The same run with the scanners' ranging noise and the IMU's white noise `times` what
    /// the fusion is told (its configured defaults), as on sensors worse than their data sheet
    /// or configuration says.
    fn with_sensors_noisier(mut self, times: f64) -> Self {
        let told = [0, 1].map(|k| self.scenario.scanners[k].range_sigma_m);
        for scanner in &mut self.scenario.scanners {
            scanner.range_sigma_m *= times;
        }
        let imu = self.scenario.imu.as_mut().expect("the scenes carry an IMU");
        imu.gyro.noise_density *= times;
        imu.accel.noise_density *= times;
        self.told_range_sigma_m = Some(told);
        self
    }

    /// The same run at `epoch_rate_hz` odometry epochs, the scanners kept at 10 Hz above 4 Hz
    /// (every fourth of their 40 Hz scans).
    fn at_epoch_rate(mut self, epoch_rate_hz: f64) -> Self {
        self.epoch_rate_hz = epoch_rate_hz;
        if epoch_rate_hz > 4.0 {
            for scanner in &mut self.scenario.scanners {
                scanner.skip = 3;
            }
        }
        self
    }

    /// The same run measured by `method` (`odometry.method`).
    fn measured_by(mut self, method: OdometryMethod) -> Self {
        self.method = method;
        self
    }

    /// The scene `{prefix}{seed}`, started still for even seeds and in motion 20-40 s in for
    /// odd ones, its sensors' noise drawn from `seed` or, with `HONEST_NOISE_DRAW=k`, from the
    /// k-th other draw.
    fn drawn(prefix: &str, seed: u64) -> Self {
        let start_s = if seed.is_multiple_of(2) {
            0.0
        } else {
            20.0 + 20.0 * (seed as f64 * 0.618_034).fract()
        };
        let noise_seed = seed + NOISE_DRAW_STRIDE * study_noise_draw();
        Self::new(&format!("{prefix}{seed}"), noise_seed, start_s)
    }

    fn until(mut self, end_s: f64) -> Self {
        self.scenario.duration_s = end_s;
        self
    }
}

/// One ODOMETRY message as the autopilot reads it, with the truth beside it.
#[derive(Debug, Clone, Copy)]
struct Message {
    t: f64,
    quality: i8,
    reset_counter: u8,
    /// Body-frame velocity error, m/s.
    error: Vector3<f64>,
    /// Reported body-frame velocity sigmas, m/s.
    sigma: Vector3<f64>,
    position: Vector3<f64>,
    /// Reported NED velocity, m/s.
    velocity: Vector3<f64>,
}

impl Message {
    fn valid(&self) -> bool {
        self.quality >= 1
    }

    fn normalised(&self) -> Vector3<f64> {
        self.error.component_div(&self.sigma)
    }
}

/// The simulator through the fusion with the daemon's defaults (as `simulate` writes the rig's
/// configuration), with the quality the PX4 profile sends.
fn fly(trial: &Trial) -> Vec<Message> {
    let mut simulator = Simulator::with_seed(&trial.scenario, trial.seed).unwrap();
    let mut settings = FusionSettings::default();
    settings.filter.imu_mount_rpy_deg = simulator.imu().unwrap().mount_rpy_deg;
    settings.odometry.method = trial.method;
    settings.fusion.epoch_rate_hz = trial.epoch_rate_hz;
    let mut setups = simulator.scanner_setups().unwrap();
    if let Some(told) = trial.told_range_sigma_m {
        for (setup, sigma) in setups.iter_mut().zip(told) {
            setup.range_sigma_m = Some(sigma);
        }
    }
    let mut fusion = Fusion::new(settings, setups).unwrap();
    let policy = QualityPolicy::default();
    let trajectory = trial.scenario.trajectory.clone();
    let silenced = |t: f64, imu: bool| trial.outage.is_some_and(|o| o.silences(t, imu));
    let mut next_message = trial.start_s;
    let mut messages = Vec::new();
    while let Some(event) = simulator.next_event() {
        let t = event.time();
        if t < trial.start_s {
            continue;
        }
        match event {
            SimEvent::Imu(sample) if !silenced(t, true) => {
                let Some(estimate) = fusion.push_imu(sample) else {
                    continue;
                };
                if estimate.t < next_message {
                    continue;
                }
                next_message += 1.0 / MESSAGE_RATE_HZ;
                let truth = trajectory.kinematics(estimate.t);
                messages.push(Message {
                    t: estimate.t,
                    quality: policy.quality(&estimate),
                    reset_counter: estimate.reset_counter,
                    error: estimate.body_velocity() - truth.q.inverse_transform_vector(&truth.v),
                    sigma: estimate
                        .body_velocity_covariance()
                        .diagonal()
                        .map(f64::sqrt),
                    position: estimate.position,
                    velocity: estimate.velocity,
                });
            }
            SimEvent::Scan { scan, .. } if !silenced(t, false) => {
                fusion.push_scan(scan);
            }
            _ => {}
        }
    }
    messages
}

/// The autopilot's view of one or more runs.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
struct Verdict {
    messages: usize,
    valid: usize,
    /// Per body axis, among valid messages: the share within 3 reported sigmas.
    inside_3_sigma: [f64; 3],
    /// Per body axis, among valid messages: the mean normalised error squared.
    mean_nees: [f64; 3],
    worst_valid_error_mps: f64,
    /// Largest position step between consecutive messages with the same reset counter that the
    /// reported velocity does not explain, m: a jump the autopilot would fuse as motion.
    largest_step_m: f64,
    resets: usize,
}

impl Verdict {
    fn of(messages: &[Message]) -> Self {
        let valid: Vec<&Message> = messages.iter().filter(|m| m.valid()).collect();
        let n = valid.len().max(1) as f64;
        let per_axis = |f: &dyn Fn(f64) -> f64| -> [f64; 3] {
            std::array::from_fn(|axis| {
                valid.iter().map(|m| f(m.normalised()[axis])).sum::<f64>() / n
            })
        };
        let same_frame = messages
            .windows(2)
            .filter(|pair| pair[0].reset_counter == pair[1].reset_counter);
        Self {
            messages: messages.len(),
            valid: valid.len(),
            inside_3_sigma: per_axis(&|z| f64::from(u8::from(z.abs() <= 3.0))),
            mean_nees: per_axis(&|z| z * z),
            worst_valid_error_mps: valid.iter().map(|m| m.error.amax()).fold(0.0, f64::max),
            largest_step_m: same_frame.map(unexplained_step).fold(0.0, f64::max),
            resets: messages
                .windows(2)
                .filter(|pair| pair[0].reset_counter != pair[1].reset_counter)
                .count(),
        }
    }

    /// All the runs' valid messages together.
    fn pooled(runs: &[Vec<Message>]) -> Self {
        let all: Vec<Message> = runs.iter().flatten().copied().collect();
        let largest_step_m = runs
            .iter()
            .map(|r| Self::of(r).largest_step_m)
            .fold(0.0, f64::max);
        Self {
            largest_step_m,
            resets: runs.iter().map(|r| Self::of(r).resets).sum(),
            ..Self::of(&all)
        }
    }

    /// Usable in half the messages or more, and honest.
    fn assert_usable_and_honest(&self, label: &str) {
        assert!(
            self.valid * 2 >= self.messages,
            "{label}: usable in only {} of {} messages",
            self.valid,
            self.messages
        );
        self.assert_honest(label);
    }

    fn assert_honest(&self, label: &str) {
        for axis in 0..3 {
            assert!(
                self.inside_3_sigma[axis] >= INSIDE_3_SIGMA,
                "{label}: axis {axis} only {:.3} inside 3 sigma: {self:?}",
                self.inside_3_sigma[axis]
            );
            assert!(
                self.mean_nees[axis] <= MEAN_NEES,
                "{label}: axis {axis} mean NEES {:.2}: {self:?}",
                self.mean_nees[axis]
            );
        }
        assert!(
            self.largest_step_m <= STEP_M,
            "{label}: a {:.2} m step without a reset: {self:?}",
            self.largest_step_m
        );
    }
}

/// How far the position moved between two messages beyond what their velocities carried it.
fn unexplained_step(pair: &[Message]) -> f64 {
    let travelled = (pair[0].velocity + pair[1].velocity) * 0.5 * (pair[1].t - pair[0].t);
    (pair[1].position - pair[0].position - travelled).norm()
}

/// How many valid messages lie outside 3 reported sigmas on some axis.
fn usable_outside_3_sigma(run: &[Message]) -> usize {
    run.iter()
        .filter(|m| m.valid() && m.normalised().amax() > 3.0)
        .count()
}

/// Seconds from the start (or from `after_s`) to the first valid message.
fn first_valid_after(messages: &[Message], after_s: f64) -> Option<f64> {
    messages
        .iter()
        .find(|m| m.t >= after_s && m.valid())
        .map(|m| m.t - after_s)
}

/// The epoch rate `HONEST_EPOCH_RATE_HZ` sets for every trial, if set.
fn study_epoch_rate_hz() -> Option<f64> {
    std::env::var("HONEST_EPOCH_RATE_HZ").ok().map(|rate| {
        rate.parse()
            .expect("HONEST_EPOCH_RATE_HZ: an epoch rate in Hz, such as 10")
    })
}

/// Runs the trials over the machine's cores, in order, at their own epoch rate (the paper's
/// 1 Hz unless they say otherwise) or at `HONEST_EPOCH_RATE_HZ`.
fn fly_all(trials: &[Trial]) -> Vec<Vec<Message>> {
    let study_rate = study_epoch_rate_hz();
    let at_rate: Vec<Trial> = trials
        .iter()
        .map(|trial| match study_rate {
            Some(rate) => trial.clone().at_epoch_rate(rate),
            None => trial.clone(),
        })
        .collect();
    let workers = std::thread::available_parallelism().map_or(1, usize::from);
    let per_worker = at_rate.len().div_ceil(workers).max(1);
    std::thread::scope(|scope| {
        let handles: Vec<_> = at_rate
            .chunks(per_worker)
            .map(|chunk| scope.spawn(move || chunk.iter().map(fly).collect::<Vec<_>>()))
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    })
}

/// `runs` trials of `name`, seeds 100 on, each starting at a different point of the first
/// `window_s` seconds (golden-ratio spread) and lasting `length_s`.
fn starts_in_motion(name: &str, runs: u64, window_s: f64, length_s: f64) -> Vec<Trial> {
    (0..runs)
        .map(|k| {
            let start_s = (k as f64 * 0.618_034).fract() * window_s;
            Trial::new(name, 100 + k, start_s).until(start_s + length_s)
        })
        .collect()
}

/// Four two-minute runs of the bare corridor by `method`: usable, and honest along it.
fn assert_the_corridor_is_honest(method: OdometryMethod) -> Verdict {
    let trials: Vec<Trial> = (0..4)
        .map(|k| {
            Trial::new("bare-corridor", 100 + k, 0.0)
                .until(120.0)
                .measured_by(method)
        })
        .collect();
    let runs = fly_all(&trials);
    let verdict = Verdict::pooled(&runs);
    println!(
        "bare-corridor, {method:?}, 4 runs: {}",
        serde_json::to_string(&verdict).unwrap()
    );
    assert!(verdict.valid > 0, "never usable: {verdict:?}");
    verdict.assert_honest("bare-corridor");
    verdict
}

#[test]
fn a_bare_corridor_never_tells_the_autopilot_a_wrong_velocity_is_good() {
    assert_the_corridor_is_honest(OdometryMethod::Pairs);
}

/// On the plane map the corridor's length is faced by nothing but the cabinet: the map holds
/// the position along it where it was (`Eskf::held_along`). Before, every epoch's update moved
/// it by decimetres: 134 pose jumps in these four runs, and 94 % of the messages inside 3
/// sigma along it. The place is now corrected only as the velocity it was walked at is
/// measured again, through the map's origin (`MapStates::hand_place_to_map`): 31 jumps, each
/// with `reset_counter` (the pairs: 341), where the place was never corrected before.
#[test]
fn on_the_plane_map_the_bare_corridor_is_honest_and_the_pose_seldom_jumps() {
    let verdict = assert_the_corridor_is_honest(OdometryMethod::Map);
    let runs_s = 4.0 * 120.0;
    assert!(
        (verdict.resets as f64) < runs_s / 10.0,
        "a jump more often than every 10 s: {verdict:?}"
    );
}

/// A scanner that ranges three times worse than its `range_sigma_m` and an IMU three times
/// noisier than its configured densities: the fusion measures both (`odometry/ranging_noise.rs`,
/// `filter/imu_noise.rs`). Told only the configuration, this room had 89 % of its usable
/// messages inside 3 sigma across the room with the ranges alone noisier, and 79 % (NEES 19.7)
/// with the IMU alone.
#[test]
fn an_open_room_seen_by_sensors_noisier_than_configured_is_honest() {
    let trials: Vec<Trial> = (0..2)
        .map(|k| Trial::new("open-room", 100 + k, 0.0).with_sensors_noisier(3.0))
        .collect();
    let verdict = Verdict::pooled(&fly_all(&trials));
    assert!(verdict.valid * 2 >= verdict.messages, "{verdict:?}");
    verdict.assert_honest("open-room, sensors three times noisier");
}

/// The hall walk on the plane map with the same noisier sensors. The pairs handed over once the
/// velocity predicted the second to a sure match (0.1 m): seed 103 handed over with the velocity
/// along the hall a tenth of a metre a second off and vague, the map's updates then taught the
/// pitch milliradians off, and velocities 2.3 m/s off went out usable (mean NEES 96-192 per
/// axis). The pairs now wait until it predicts the second to the map's own 2 cm
/// (`Fusion::ready_for_the_map`). Seed 116 beside it is one that stayed honest.
#[test]
fn on_the_plane_map_a_hall_seen_by_sensors_noisier_than_configured_is_honest() {
    let trials: Vec<Trial> = [103, 116]
        .map(|seed| {
            Trial::new("hall-walk", seed, 0.0)
                .with_sensors_noisier(3.0)
                .measured_by(OdometryMethod::Map)
        })
        .to_vec();
    let verdict = Verdict::pooled(&fly_all(&trials));
    assert!(verdict.valid * 2 >= verdict.messages, "{verdict:?}");
    verdict.assert_honest("hall-walk on the map, sensors three times noisier");
}

#[test]
fn a_flight_started_in_its_hover_is_usable_within_10_s_and_honest() {
    assert_the_flight_started_in_its_hover_is_usable(OdometryMethod::Pairs);
}

/// The plane map starts on the pairs (`Fusion::seed_map`): until the velocity is known a line
/// fits any parallel surface within metres.
#[test]
fn on_the_plane_map_a_flight_started_in_its_hover_is_usable_within_10_s_and_honest() {
    assert_the_flight_started_in_its_hover_is_usable(OdometryMethod::Map);
}

/// At 10 Hz epochs the hallway's corner turns the body 2-3 degrees between an epoch's
/// reference time and the clone its relative pose is bridged to. The bridge kept the directions
/// the planes observed in the reference epoch's axes, so the displacement anchored along the
/// unobserved hallway, the filter's own velocity of a start in motion, leaked into the observed
/// rows as if measured: flights started 14-17 s in sent along-track velocities 2 m/s off at
/// quality 10-17. On the map the same starts handed over with 0.55 m/s of sigma along the
/// hallway, which predicts one 10 Hz epoch to a sure match but not the second the map's
/// surfaces are kept for, and sent 1.9 m/s off as usable (docs/autopilot.md, "Above 1 Hz").
#[test]
fn a_flight_started_in_motion_at_10_hz_sends_no_wrong_velocity_as_usable() {
    for method in [OdometryMethod::Pairs, OdometryMethod::Map] {
        let trials: Vec<Trial> = starts_in_motion("hallway-flight", 20, 33.0, 10.0)
            .into_iter()
            .map(|trial| trial.at_epoch_rate(10.0).measured_by(method))
            .collect();
        let verdict = Verdict::pooled(&fly_all(&trials));
        assert!(verdict.valid > 0, "{method:?} never usable: {verdict:?}");
        verdict.assert_honest(&format!(
            "hallway-flight, started in motion, 10 Hz, {method:?}"
        ));
    }
}

/// A hover started in motion, at 10 Hz on the plane map: the hallway's length is faced by one
/// wall, whose direction the start learns and holds in doubt until a check vouches for it. No
/// one 10 Hz epoch can see a wall move at the detection speed, so every check said `unchecked`
/// while the velocity was known to 2 mm/s, and these starts became usable only after 34.8 and
/// 42.6 s. Each lone direction is now checked over the second's epochs too
/// (`fusion::checks_over_second`), and a surprise among ten updates a second counts as one
/// among them (`filter::surprises_one_of`); with the first alone, the first start still took
/// 10.9 s.
#[test]
fn on_the_plane_map_at_10_hz_a_hover_started_in_motion_is_usable_within_10_s() {
    let trials: Vec<Trial> = starts_in_motion("hallway-hover", 10, 400.0, 20.0)
        .into_iter()
        .filter(|trial| [102, 109].contains(&trial.seed))
        .map(|trial| trial.at_epoch_rate(10.0).measured_by(OdometryMethod::Map))
        .collect();
    assert_usable_within_10_s_and_honest(&trials, "hallway-hover, started in motion, 10 Hz, Map");
}

fn assert_the_flight_started_in_its_hover_is_usable(method: OdometryMethod) {
    let trials: Vec<Trial> = starts_in_motion("hallway-flight", 4, 9.0, 20.0)
        .into_iter()
        .map(|trial| trial.measured_by(method))
        .collect();
    assert_usable_within_10_s_and_honest(
        &trials,
        &format!("hallway-flight, started in motion, {method:?}"),
    );
}

/// Each of `trials`, started in motion, usable within 10 s of its start; all of them honest.
fn assert_usable_within_10_s_and_honest(trials: &[Trial], label: &str) {
    let runs = fly_all(trials);
    for (trial, run) in trials.iter().zip(&runs) {
        let first = first_valid_after(run, trial.start_s);
        assert!(
            first.is_some_and(|s| s <= 10.0),
            "{label}: started at {:.1} s: first valid {first:?}",
            trial.start_s
        );
    }
    Verdict::pooled(&runs).assert_honest(label);
}

/// The open room with the paper's rig, started in its hover: the walls to either side, the
/// wall behind as a plumb plane through one level line, no floor. Until stop 38 the anchored
/// solve refused every such epoch, nothing was fused for ten seconds, and the filter restarted
/// at 6 m/s (docs/autopilot.md, "A start in motion that fused nothing").
#[test]
fn an_open_room_started_in_its_hover_is_usable_within_10_s_and_honest() {
    let start_s = 0.618_034 * 90.0;
    let trial = Trial::new("open-room", 101, start_s).until(start_s + 20.0);
    let run = fly(&trial);
    let first = first_valid_after(&run, start_s);
    assert!(first.is_some_and(|s| s <= 10.0), "first valid {first:?}");
    Verdict::of(&run).assert_honest("open-room, started in motion");
}

/// The pairs hand over to the plane map only once the velocity places surfaces surely and
/// nothing fused awaits a check. Handed over earlier, the map either stayed unusable for the
/// whole run (`random-room-5`, rolled rig) or placed its surfaces loosely and then locked a
/// vertical velocity 0.34 m/s off as usable (`random-room-9`).
#[test]
fn started_late_in_a_random_room_the_plane_map_takes_over_usable_and_honest() {
    for (seed, start_s) in [(5, 21.8), (9, 31.2)] {
        let name = format!("random-room-{seed}");
        let run = fly(&Trial::new(&name, seed, start_s).measured_by(OdometryMethod::Map));
        Verdict::of(&run).assert_usable_and_honest(&format!("{name} from {start_s} s"));
    }
}

/// Along a bare corridor at 10 Hz the map's lines were linearised where the body thought it
/// was along the corridor, metres off, and taught the floor and the walls a tilt they did not
/// have; the pitch and the velocity followed (seeds 109 and 112: 0.78 and 0.60 of their usable
/// messages inside 3 sigma along the corridor, mean NEES 5.3 and 7.2). The body's place there
/// is now the map's to carry (`MapStates::hand_place_to_map`).
#[test]
fn on_the_plane_map_at_10_hz_a_bare_corridor_stays_honest_along_its_length() {
    assert_usable_and_honest_on_the_map_at_10_hz("bare-corridor", [109, 112]);
}

/// Each seed of `scenario` flown still-started on the plane map at 10 Hz, usable and honest.
fn assert_usable_and_honest_on_the_map_at_10_hz(scenario: &str, seeds: [u64; 2]) {
    let trials: Vec<Trial> = seeds
        .map(|seed| {
            Trial::new(scenario, seed, 0.0)
                .measured_by(OdometryMethod::Map)
                .at_epoch_rate(10.0)
        })
        .to_vec();
    for (trial, run) in trials.iter().zip(fly_all(&trials)) {
        let verdict = Verdict::of(&run);
        println!(
            "seed {}: {}",
            trial.seed,
            serde_json::to_string(&verdict).unwrap()
        );
        verdict.assert_usable_and_honest(&format!("{scenario} at 10 Hz, seed {}", trial.seed));
    }
}

/// At 10 Hz a board carried along the corridor at 0.5 m/s moves 5 cm an epoch: its surface,
/// placed anew each epoch, once matched its next sighting within the prediction's doubt, faced
/// the corridor's length alone, and gave the body the board's speed: 0.5 m/s off at a sigma of
/// 3 mm/s, quality 100 (seeds 109 and 112: 0.53 and 0.46 of their usable messages inside
/// 3 sigma along the corridor, mean NEES 880 and 1160). Above 1 Hz a lone surface younger than
/// the plane confirmation's second is now checked as strictly as its age (docs/design.md 4.11,
/// "Lone surfaces").
#[test]
fn on_the_plane_map_at_10_hz_a_carried_board_lends_the_body_none_of_its_speed() {
    assert_usable_and_honest_on_the_map_at_10_hz("board-corridor", [109, 112]);
}

/// Narrow corridors nobody tuned on (1.4-1.6 m wide, bare but for one cabinet), walked down
/// and back, the body turning round with its track: to the far end at 1 m/s
/// (`random-corridor-4`) and 7.6 m in at 0.5 m/s (`random-corridor-10`). On the pairs the
/// floor and the walls read the same tilt error through the motion along the corridor every
/// epoch as if it were new; the tilt and the accelerometer's bias came out of the turn 4-5
/// sigma off, and the velocity along the corridor with them: 2 m/s off at quality 10-60, 0.55
/// and 0.85 of the usable messages inside 3 sigma, mean NEES 9 and 2.2 (docs/autopilot.md,
/// "Corridors nobody tuned on"). That motion, known surely, is now the lever of the attitude
/// error in the Jacobian (`relative_pose::sure_lever`). The plane map was honest on both.
/// Each is judged on six draws of its noise, pooled: one draw alone is a roll of the dice at
/// this threshold (on the pairs, corridor 10's draw 2 had a mean NEES of 2.2 when its draw 0
/// had 1.2, and the start's accelerometer sway swapped the two).
#[test]
fn a_corridor_walked_down_and_back_is_honest() {
    for method in [OdometryMethod::Pairs, OdometryMethod::Map] {
        for seed in [4, 10] {
            let trials: Vec<Trial> = (0..6)
                .map(|draw| {
                    let name = format!("random-corridor-{seed}");
                    Trial::new(&name, seed + draw * NOISE_DRAW_STRIDE, 0.0).measured_by(method)
                })
                .collect();
            Verdict::pooled(&fly_all(&trials))
                .assert_usable_and_honest(&format!("random-corridor-{seed}, {method:?}"));
        }
    }
}

/// `random-corridor-25` started 29 s in: a person walking ahead at the platform's pace was the
/// only plane facing along the corridor for two epochs, and the next check found them where the
/// prediction they had taught put them. Released on that, 1199 messages went out usable with
/// the velocity along the corridor 1.2-4 m/s off, all outside 3 sigma. A direction learnt from
/// a lone plane now waits for 2 s of agreement at every epoch (`fusion/witnesses.rs`).
#[test]
fn a_person_walking_ahead_after_a_start_in_motion_is_not_taken_for_a_wall() {
    let trials: Vec<Trial> = [OdometryMethod::Pairs, OdometryMethod::Map]
        .map(|method| Trial::drawn("random-corridor-", 25).measured_by(method))
        .into();
    for (trial, run) in trials.iter().zip(fly_all(&trials)) {
        let wrong = usable_outside_3_sigma(&run);
        assert_eq!(wrong, 0, "{:?}: {:?}", trial.method, Verdict::of(&run));
    }
}

/// `random-corridor-49` started 25.7 s in, on three draws of its noise. With nothing facing
/// along the corridor for 18 s, the first surface that did was paired with another one 2 m from
/// it, as the start's vague prior allowed, and taught the filter a velocity 2.8 m/s off. Then,
/// standing still, the odometer paired every surface facing along the corridor with another
/// one 2.7 m away, as that velocity predicted, and each pairing vouched for it: 1150-1240
/// messages went out usable, every one 2.7 m/s off at a sigma of millimetres a second. A
/// pairing along a taught direction is now doubted as vaguely as before it was taught
/// (`witnesses::Provisional::widened`). Where the wrong velocity forced a restart, the
/// restart's levelling was read as a turn and taught the gyro bias 1.8 mrad/s off; a restart
/// now turns the stored poses with it (`Eskf::reinitialise`).
#[test]
fn a_surface_paired_with_another_after_a_start_in_motion_teaches_no_usable_wrong_velocity() {
    let trials: Vec<Trial> = [2, 4, 5]
        .into_iter()
        .flat_map(|draw| {
            [OdometryMethod::Pairs, OdometryMethod::Map].map(|method| Trial {
                seed: 49 + draw * NOISE_DRAW_STRIDE,
                ..Trial::drawn("random-corridor-", 49).measured_by(method)
            })
        })
        .collect();
    for (trial, run) in trials.iter().zip(fly_all(&trials)) {
        let wrong = usable_outside_3_sigma(&run);
        let verdict = Verdict::of(&run);
        let label = format!("noise seed {}, {:?}: {verdict:?}", trial.seed, trial.method);
        assert_eq!(wrong, 0, "{label}");
        assert!(verdict.worst_valid_error_mps < 0.1, "{label}");
    }
}

/// `random-corridor-29` started 38.5 s in (the rolled rig), on three draws of its noise. After
/// a restart 11 s in, the one plane that saw the pitch joined a floor line 1.6 m ahead to a
/// line on the end wall 14.7 m ahead: the two cross, meet within their noise, and lie 2.3 deg
/// from the vertical the start knew to 30 mrad, so the plane passed for a level static surface.
/// Its slope changes as the platform closes on the end wall, so it put the relative pitch
/// 1.8 mrad off at a sigma of 0.05 mrad; trusted as a static surface, it taught the gyro's
/// pitch-rate bias 1.6 mrad/s off, and gravity drove the velocity along the corridor off three
/// times as fast as its sigma. A lone plane's rotation is now taken on trust only under a prior
/// that leaves no room for another surface, as its displacement is (`witnesses::LoneWitnesses`).
#[test]
fn a_fictitious_floor_after_a_start_in_motion_teaches_no_gyro_bias() {
    let trials: Vec<Trial> = [0, 1, 5]
        .into_iter()
        .flat_map(|draw| {
            [OdometryMethod::Pairs, OdometryMethod::Map].map(|method| Trial {
                seed: 29 + draw * NOISE_DRAW_STRIDE,
                ..Trial::drawn("random-corridor-", 29).measured_by(method)
            })
        })
        .collect();
    for (trial, run) in trials.iter().zip(fly_all(&trials)) {
        let label = format!(
            "noise seed {}, {:?}: {:?}",
            trial.seed,
            trial.method,
            Verdict::of(&run)
        );
        assert_eq!(usable_outside_3_sigma(&run), 0, "{label}");
    }
}

/// `random-corridor-46` (a still start) on three draws of its noise, on the pairs: the walk
/// along the corridor begins with an acceleration under what the stillness test sees, so the
/// zero-velocity updates held the velocity at zero while the truth was 3 cm/s and took the
/// acceleration for accelerometer bias and pitch; along the corridor, where nothing observes
/// them, the velocity error then grew three times as fast as its sigma. Motion that ends the
/// start now gives the accelerometer bias and the velocity back the uncertainty of a start
/// that moved unseen (`filter.still_sway_force_sigma_mps2`).
#[test]
fn a_walk_that_starts_under_the_stillness_threshold_leaves_the_velocity_honest() {
    let trials: Vec<Trial> = [3, 4, 5]
        .into_iter()
        .map(|draw| Trial {
            seed: 46 + draw * NOISE_DRAW_STRIDE,
            ..Trial::drawn("random-corridor-", 46)
        })
        .collect();
    for (trial, run) in trials.iter().zip(fly_all(&trials)) {
        Verdict::of(&run).assert_honest(&format!("noise seed {}", trial.seed));
    }
}

/// The pairs hand over to the plane map only after an epoch that observed nothing new: in
/// this flight the end wall comes into view 37 s in, and the map that took over then held a
/// velocity 0.1 m/s off at 1 cm/s sigma. Judged over 20 s: since a lone plane's rotation after
/// a start in motion is held in doubt until checked, the first usable message comes 10.1 s in
/// (6.1 s before, and those first 4 s had a mean NEES of 4 across the body).
#[test]
fn on_the_plane_map_a_flight_started_before_its_end_wall_comes_into_view_is_honest() {
    let start_s = 31.16;
    let trial = Trial::new("hallway-flight", 108, start_s)
        .until(start_s + 20.0)
        .measured_by(OdometryMethod::Map);
    let verdict = Verdict::of(&fly(&trial));
    assert!(
        verdict
            .inside_3_sigma
            .iter()
            .all(|&share| share >= INSIDE_3_SIGMA),
        "hallway-flight from 31.16 s on the plane map: too few messages inside 3 sigma (one \
         run is too short to judge its mean NEES): {verdict:?}"
    );
}

#[test]
fn after_losing_every_sensor_for_5_s_it_is_usable_within_10_s_and_never_wrong() {
    let mut trial = Trial::new("hallway-hover", 3, 0.0).until(90.0);
    trial.outage = Some(Outage {
        from_s: 60.0,
        to_s: 65.0,
        imu_too: true,
    });
    let run = fly(&trial);
    let after = first_valid_after(&run, 65.0);
    assert!(
        after.is_some_and(|s| s <= 10.0),
        "first valid after the outage: {after:?}"
    );
    let during = run
        .iter()
        .filter(|m| (60.0..65.0).contains(&m.t) && m.valid())
        .count();
    assert_eq!(
        during, 0,
        "nothing usable is sent while the sensors are away"
    );
    Verdict::of(&run).assert_honest("hallway-hover with an outage");
    assert!(
        Verdict::of(&run).resets >= 1,
        "the realignment re-anchors the autopilot"
    );
}

fn study(label: &str, trials: &[Trial]) -> (Verdict, Vec<Option<f64>>) {
    let runs = fly_all(trials);
    let verdict = Verdict::pooled(&runs);
    let first: Vec<Option<f64>> = trials
        .iter()
        .zip(&runs)
        .map(|(trial, run)| first_valid_after(run, trial.start_s))
        .collect();
    println!(
        "{label}: {} first valid {:?}",
        serde_json::to_string(&verdict).unwrap(),
        first
    );
    (verdict, first)
}

/// The 20-run studies that judge honesty alone, by name: trials of the built-in scenes, still
/// and started in motion.
fn honesty_studies() -> Vec<(&'static str, Vec<Trial>)> {
    let still =
        |name: &str| -> Vec<Trial> { (0..20).map(|k| Trial::new(name, 100 + k, 0.0)).collect() };
    vec![
        ("bare-corridor", still("bare-corridor")),
        (
            "bare-corridor started in motion",
            starts_in_motion("bare-corridor", 20, 230.0, 30.0),
        ),
        ("board-corridor", still("board-corridor")),
        (
            "board-corridor started in motion",
            starts_in_motion("board-corridor", 20, 230.0, 30.0),
        ),
        ("open-room", still("open-room")),
        (
            "open-room started in motion",
            starts_in_motion("open-room", 20, 90.0, 30.0),
        ),
        ("hall-walk", still("hall-walk")),
        (
            "hallway-flight started in motion",
            starts_in_motion("hallway-flight", 20, 33.0, 10.0),
        ),
    ]
}

fn honesty_study(name: &str) {
    let (label, trials) = honesty_studies()
        .into_iter()
        .find(|(label, _)| *label == name)
        .unwrap();
    study(&format!("{label}, 20 runs"), &trials)
        .0
        .assert_honest(label);
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_bare_corridor_20_runs() {
    honesty_study("bare-corridor");
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_bare_corridor_started_in_motion_20_runs() {
    honesty_study("bare-corridor started in motion");
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_board_corridor_20_runs() {
    honesty_study("board-corridor");
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_board_corridor_started_in_motion_20_runs() {
    honesty_study("board-corridor started in motion");
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_open_room_20_runs() {
    honesty_study("open-room");
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_open_room_started_in_motion_20_runs() {
    honesty_study("open-room started in motion");
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_hall_walk_20_runs() {
    honesty_study("hall-walk");
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_flight_started_in_motion_20_runs() {
    honesty_study("hallway-flight started in motion");
}

/// Every honesty study again on the plane map (docs/accuracy.md, "The plane map"); each is
/// printed, and the test fails at the end naming those not honest.
#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_plane_map_honesty_20_runs() {
    every_honesty_study("on the plane map", |trial| {
        trial.measured_by(OdometryMethod::Map)
    });
}

/// Every honesty study again with sensors three times noisier than the fusion is told
/// (docs/accuracy.md, "Noisier sensors than configured").
#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_sensors_noisier_than_configured_20_runs() {
    every_honesty_study("with sensors three times noisier", |trial| {
        trial.with_sensors_noisier(3.0)
    });
}

/// The same on the plane map (docs/accuracy.md, "Noisier sensors than configured"): the hall
/// walk failed it until the pairs handed over only on a velocity known to the map's own 2 cm
/// over the second.
#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_plane_map_sensors_noisier_than_configured_20_runs() {
    every_honesty_study(
        "on the plane map with sensors three times noisier",
        |trial| {
            trial
                .with_sensors_noisier(3.0)
                .measured_by(OdometryMethod::Map)
        },
    );
}

/// Runs every honesty study with its trials `changed`, prints each, and fails at the end
/// naming those not honest (a study that was never usable is not judged).
fn every_honesty_study(change: &str, changed: impl Fn(Trial) -> Trial) {
    let mut failed = Vec::new();
    for (label, trials) in honesty_studies() {
        let trials: Vec<Trial> = trials.into_iter().map(&changed).collect();
        let (verdict, first) = study(&format!("{label} {change}, 20 runs"), &trials);
        let usable = first
            .iter()
            .filter(|s| s.is_some_and(|s| s <= 10.0))
            .count();
        println!("  usable within 10 s in {usable} of 20");
        // Never usable claims nothing: with ranges three times noisier the bare corridor's
        // length stays unobserved for good.
        let judged = verdict.valid > 0;
        if judged && std::panic::catch_unwind(|| verdict.assert_honest(label)).is_err() {
            failed.push(label);
        }
    }
    assert!(failed.is_empty(), "not honest {change}: {failed:?}");
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_hover_started_in_motion_20_runs() {
    hover_started_in_motion(OdometryMethod::Pairs);
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_plane_map_hover_started_in_motion_20_runs() {
    hover_started_in_motion(OdometryMethod::Map);
}

fn hover_started_in_motion(method: OdometryMethod) {
    let trials: Vec<Trial> = starts_in_motion("hallway-hover", 20, 400.0, 60.0)
        .into_iter()
        .map(|trial| trial.measured_by(method))
        .collect();
    let label = format!("hallway-hover started in motion, {method:?}, 20 runs");
    let (verdict, first) = study(&label, &trials);
    verdict.assert_honest("hallway-hover started in motion");
    assert!(
        first.iter().all(|s| s.is_some_and(|s| s <= 10.0)),
        "{first:?}"
    );
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_outages_in_flight_20_runs() {
    outages_in_flight(OdometryMethod::Pairs);
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_plane_map_outages_in_flight_20_runs() {
    outages_in_flight(OdometryMethod::Map);
}

fn outages_in_flight(method: OdometryMethod) {
    let trials: Vec<Trial> = (0..20)
        .map(|k| {
            let from_s = 45.0 + 10.0 * (k as f64 * 0.618_034).fract();
            let mut trial = Trial::new("hallway-hover", 100 + k, 0.0)
                .until(from_s + 40.0)
                .measured_by(method);
            trial.outage = Some(Outage {
                from_s,
                to_s: from_s + 2.0 + 8.0 * (k as f64 * 0.414_214).fract(),
                imu_too: k % 2 == 0,
            });
            trial
        })
        .collect();
    let runs = fly_all(&trials);
    let after: Vec<Option<f64>> = trials
        .iter()
        .zip(&runs)
        .map(|(trial, run)| first_valid_after(run, trial.outage.unwrap().to_s))
        .collect();
    let verdict = Verdict::pooled(&runs);
    println!(
        "hallway-hover with 2-10 s outages, {method:?}, 20 runs: {} valid again after {after:?}",
        serde_json::to_string(&verdict).unwrap()
    );
    verdict.assert_honest("outages");
    assert!(
        after.iter().all(|s| s.is_some_and(|s| s <= 10.0)),
        "{after:?}"
    );
}

/// Rooms nobody tuned the odometer on (`random-room-N`, seeds 1-20): the even seeds carry the
/// paper's rig and start still, the odd ones the rolled rig and start in motion 20-40 s in. A
/// short run in one room is judged more loosely than the pooled studies (inside 3 sigma 95 %,
/// mean NEES 2.5 per axis); one room in twenty may fail it (docs/autopilot.md names it), a
/// second is a regression. `HONEST_SEEDS=21-60` draws other seeds.
#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_random_rooms_20_runs() {
    drawn_scenes("random-room-", OdometryMethod::Pairs);
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_plane_map_random_rooms_20_runs() {
    drawn_scenes("random-room-", OdometryMethod::Map);
}

/// Corridors nobody tuned the odometer on (`random-corridor-N`, seeds 1-20), judged as the
/// random rooms are: along most of a corridor nothing measures the motion along it, and
/// whatever the corridor's width, fixtures and walk, the estimate must say so.
#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_random_corridors_20_runs() {
    drawn_scenes("random-corridor-", OdometryMethod::Pairs);
}

#[test]
#[ignore = "release-mode study (docs/autopilot.md)"]
fn study_plane_map_random_corridors_20_runs() {
    drawn_scenes("random-corridor-", OdometryMethod::Map);
}

/// The scenes `{prefix}N` for the study's seeds, the even seeds started still and the odd ones
/// in motion 20-40 s in (the odd seeds also carry the rolled rig).
fn drawn_scenes(prefix: &str, method: OdometryMethod) {
    let trials: Vec<Trial> = study_seeds()
        .map(|seed| Trial::drawn(prefix, seed).measured_by(method))
        .collect();
    let runs = fly_all(&trials);
    let mut dishonest = Vec::new();
    for (trial, run) in trials.iter().zip(&runs) {
        let verdict = Verdict::of(run);
        println!(
            "{} from {:.1} s: {} first valid {:?}",
            trial.scenario.name,
            trial.start_s,
            serde_json::to_string(&verdict).unwrap(),
            first_valid_after(run, trial.start_s)
        );
        // A run never usable claims nothing.
        let honest = verdict.valid == 0
            || (0..3)
                .all(|axis| verdict.inside_3_sigma[axis] >= 0.95 && verdict.mean_nees[axis] <= 2.5);
        if !honest {
            dishonest.push(trial.scenario.name.clone());
        }
    }
    println!(
        "{prefix}{:?}, {method:?}: {}",
        study_seeds(),
        serde_json::to_string(&Verdict::pooled(&runs)).unwrap()
    );
    assert!(
        dishonest.len() * 20 <= trials.len(),
        "not honest in {dishonest:?}"
    );
}

/// Apart from the drawn scenes' seeds, so that no draw of one scene's noise is another's.
const NOISE_DRAW_STRIDE: u64 = 1_000_000;

/// Which draw of the sensors' noise the drawn scenes fly: 0 (their own seed), or the one
/// `HONEST_NOISE_DRAW` names. A scene honest on one draw may not be on another: one unlucky
/// draw of the gyro's noise is what makes `random-corridor-32` dishonest (docs/autopilot.md).
fn study_noise_draw() -> u64 {
    std::env::var("HONEST_NOISE_DRAW").map_or(0, |draw| {
        draw.parse()
            .expect("HONEST_NOISE_DRAW: which draw of the noise, a whole number such as 1")
    })
}

/// The seeds of the drawn scenes: 1-20, or the range `HONEST_SEEDS` names (`21-60`).
fn study_seeds() -> std::ops::RangeInclusive<u64> {
    let Ok(range) = std::env::var("HONEST_SEEDS") else {
        return 1..=20;
    };
    let bounds: Vec<u64> = range
        .split('-')
        .map(|bound| {
            bound
                .parse()
                .expect("HONEST_SEEDS: a range of seeds, such as 21-60")
        })
        .collect();
    assert_eq!(
        bounds.len(),
        2,
        "HONEST_SEEDS: a range of seeds, such as 21-60"
    );
    bounds[0]..=bounds[1]
}
