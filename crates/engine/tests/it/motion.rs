//! The motion layer on its own (no campaign, no store), as a console will drive it.

use std::time::Duration;

use gonio_engine::control::Control;
use gonio_engine::motion::{Motion, MotionError};
use gonio_engine::rig::Rig;
use gonio_instrument::{AxisRole, InstrumentFile};
use gonio_scheduler::kinematics::Pose;
use gonio_scheduler::timing::TimeModel;
use gonio_simulator::recording::{check_arm_separation, physical_pieces};

/// Under the paused clock a hang becomes this timeout at once.
const NO_HANG: Duration = Duration::from_secs(24 * 3600);

fn assert_at(motion: &Motion<'_>, target: &Pose) {
    let rig = motion.rig();
    for (a, read) in rig.axes().iter().zip(motion.readback_deg()) {
        let want = target.get(a.config.role);
        assert!(
            (read - want).abs() <= a.config.tolerance_deg,
            "{} reads {read} deg, target {want} deg",
            a.config.name
        );
    }
}

#[tokio::test(start_paused = true)]
async fn motion_alone_homes_moves_safely_and_reads_back() {
    tokio::time::timeout(NO_HANG, motion_alone())
        .await
        .expect("no hang");
}

async fn motion_alone() {
    let file = InstrumentFile::simulated();
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let sim = rig.sim().expect("a dry-run rig").clone();
    sim.start_motion_recording();
    let mut motion = Motion::new(&rig, TimeModel::new(&file.instrument), 2, Control::new());
    motion.reference_all().await.expect("referenced");
    assert_eq!(motion.readback_deg().len(), rig.axes().len());

    // Arms parted from their power-up pose (together at 0), then moved in the order the plan allows, each time
    // read back within the axes' arrival tolerance.
    let poses = [
        Pose::new(-40.0, 30.0, 0.0, 0.0),
        Pose::new(-70.0, -20.0, 15.0, 90.0),
        Pose::new(-15.0, 60.0, -10.0, -45.0),
    ];
    for target in &poses {
        motion.move_to(target).await.expect("a safe move");
        motion.read_positions().await.expect("read back");
        assert_at(&motion, target);
    }
    // Swapping the arms' order would sweep one through the other: no plan allows it, and nothing moves.
    let before = motion.readback_deg().to_vec();
    match motion.move_to(&Pose::new(60.0, -15.0, -10.0, -45.0)).await {
        Err(MotionError::Impossible(why)) => assert!(why.contains("no safe move"), "{why}"),
        other => panic!("expected no safe move, got {other:?}"),
    }
    motion.read_positions().await.expect("read back");
    assert_eq!(motion.readback_deg(), before.as_slice());

    // The simulator's record of the arms' real trajectories: never closer than the separation once apart.
    let now = sim.clock().now_s();
    let records = sim.motion_records();
    let arm = |role: AxisRole| {
        records
            .iter()
            .find(|(a, _)| a.role == role)
            .map(|(a, r)| physical_pieces(a, r.motor_pieces(now)))
            .expect("the arm was recorded")
    };
    let min_sep = file.instrument.safety.min_arm_separation_deg;
    let closest = check_arm_separation(
        &arm(AxisRole::LightArm),
        &arm(AxisRole::DetectorArm),
        min_sep,
        |s| s >= min_sep - 1e-6,
    )
    .expect("arms kept apart");
    assert!(
        closest.is_finite() && closest >= min_sep - 1e-6,
        "closest {closest}"
    );
}

#[tokio::test(start_paused = true)]
async fn an_emergency_stop_halts_a_move_of_the_motion_layer() {
    tokio::time::timeout(NO_HANG, estop_mid_move())
        .await
        .expect("no hang");
}

async fn estop_mid_move() {
    let file = InstrumentFile::simulated();
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let control = Control::new();
    let mut motion = Motion::new(&rig, TimeModel::new(&file.instrument), 2, control.clone());
    motion.reference_all().await.expect("referenced");
    let far = Pose::new(-90.0, 90.0, 0.0, 0.0);
    let stop = async {
        tokio::time::sleep(Duration::from_millis(300)).await;
        control.estop();
    };
    let (moved, ()) = tokio::join!(motion.move_to(&far), stop);
    assert!(matches!(moved, Err(MotionError::Estop)), "{moved:?}");
    // Halted short of the target, and at rest.
    tokio::time::sleep(Duration::from_secs(2)).await;
    for a in rig.axes().iter().filter(|a| a.config.role == AxisRole::LightArm) {
        let s = a.driver.status().await.expect("status");
        assert!(!s.moving);
        assert!(
            s.position_deg > -85.0,
            "the light arm ran on to {} deg",
            s.position_deg
        );
    }
}
