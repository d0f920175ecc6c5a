//! `easyhec bench …`: the benchmarks (figures in docs/benchmarks.md). Per-seed lines go to
//! stderr as they come; the summary tables to stdout.

#[cfg(feature = "sim")]
use super::exit::out;
use clap::Subcommand;

#[cfg(feature = "sim")]
use easyhec::bench::{
    AccuracyBench, CoverageBench, ExploreBench, InitBench, LoopBench, MotionBench, RealBench,
    Report, RigBench, SegmentBench, SpeedBench, ViewSetsBench,
};

/// The benchmarks.
#[cfg(feature = "sim")]
#[derive(Subcommand)]
pub enum BenchCommand {
    /// Median pose error over seeded synthetic scenes, views 1..K, LM and/or Adam.
    Accuracy(AccuracyBench),
    /// Whether the reported uncertainty covers the true error as often as it claims: axes
    /// within 2σ and camera centres within the 95% bound, over seeded synthetic scenes.
    Coverage(CoverageBench),
    /// Automatic initialisation (no guess): success rate, errors and time over seeded cells
    /// with the camera anywhere on a hemisphere around the robot.
    Init(InitBench),
    /// Closed loop on seeded simulated cells: exploration vs random pose selection (median
    /// error after each view), planning time per round and compute per calibration.
    Loop(LoopBench),
    /// Planning that weighs motion time against planning by information alone, on the mock
    /// xArm in real time: wall time, motion, views and error per seeded cell.
    Motion(MotionBench),
    /// A recorded real run against its reference pose (default: the shared xArm7 set):
    /// per-view IoU, the pose, the reported 1σ against a view-level jackknife's.
    Real(RealBench),
    /// Several cameras calibrated in one run against each camera alone, on seeded simulated
    /// cells: each camera's median error with the same views, and the wall time.
    Rig(RigBench),
    /// How far 3-view selection can go: per seeded cell, the loop's explored pair and random
    /// pairs, each solved many times with fresh noise, against the selection score's
    /// prediction (docs/benchmarks.md).
    ViewSets(ViewSetsBench),
    /// The builtin segmenter: mask IoU and RGB-only calibration error on seeded simulated
    /// cells, and (with --run) its figures on a recorded run whose masks are the reference.
    Segment(SegmentBench),
    /// One exploration round on the renderer: N joint samples x K camera candidates scored by
    /// silhouette variance (docs/method.md §5), with its posing/decimation time separate.
    Explore(ExploreBench),
    /// Wall time of K-view solves, and peak memory.
    Speed(SpeedBench),
}

/// Without the simulator there is nothing to benchmark on.
#[cfg(not(feature = "sim"))]
#[derive(Subcommand)]
pub enum BenchCommand {}

#[cfg(feature = "sim")]
impl BenchCommand {
    /// Runs the benchmark and prints its summary.
    pub fn run(self) -> anyhow::Result<()> {
        let activity = super::progress::Activity::start("bench");
        let mut log = |line: &str| activity.note(line);
        let report: Report = match self {
            BenchCommand::Accuracy(b) => b.run(&mut log)?,
            BenchCommand::Coverage(b) => b.run(&mut log)?,
            BenchCommand::Init(b) => b.run(&mut log)?,
            BenchCommand::Loop(b) => b.run(&mut log)?,
            BenchCommand::Motion(b) => b.run(&mut log)?,
            BenchCommand::Real(b) => b.run(&mut log)?,
            BenchCommand::Rig(b) => b.run(&mut log)?,
            BenchCommand::ViewSets(b) => b.run(&mut log)?,
            BenchCommand::Segment(b) => b.run(&mut log)?,
            BenchCommand::Explore(b) => b.run(&mut log)?,
            BenchCommand::Speed(b) => b.run(&mut log)?,
        };
        drop(activity);
        out!("{}", report.text());
        Ok(())
    }
}

#[cfg(not(feature = "sim"))]
impl BenchCommand {
    /// Never called: the enum has no variant without the simulator.
    pub fn run(self) -> anyhow::Result<()> {
        match self {}
    }
}
