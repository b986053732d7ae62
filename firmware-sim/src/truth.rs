//! The world's truth over a run: what tests judge the gateway by, never its own belief.
//!
//! Written at exit with `--truth FILE`: JSON (`.json`) with a summary and the samples, or
//! CSV (any other extension) with one row per sample:
//! `t,x,y,heading,v_left,v_right,min_clearance,wall_clearance,contact,o0x,o0y,o1x,...`
//! (metres, radians, m/s; `contact` 0/1). Samples are taken every 20 ms of real time.

use serde::Serialize;
use std::io::Write as _;
use std::path::Path;

use crate::world::World;

pub const SAMPLE_PERIOD: f64 = 0.02;

#[derive(Debug, Clone, Serialize)]
pub struct TruthSample {
    pub t: f64,
    pub x: f64,
    pub y: f64,
    pub heading: f64,
    pub wheel_speeds: [f64; 2],
    /// Smallest footprint gap to any obstacle now, m (`null` without obstacles).
    pub min_clearance: Option<f64>,
    pub wall_clearance: Option<f64>,
    pub contact: bool,
    pub obstacles: Vec<[f64; 2]>,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct TruthSummary {
    pub duration: f64,
    pub min_obstacle_clearance: Option<f64>,
    pub min_wall_clearance: Option<f64>,
    pub first_contact: Option<f64>,
    /// The first contact: what, and whether the robot drove into it (active) or was hit.
    pub contact: Option<crate::world::Contact>,
    pub path_length: f64,
    pub final_position: [f64; 2],
    pub peak_wheel_speed: [f64; 2],
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct TruthRecord {
    pub summary: TruthSummary,
    pub samples: Vec<TruthSample>,
}

impl TruthRecord {
    /// Take a sample of the world now.
    pub fn record(&mut self, world: &World) {
        let pose = world.pose();
        let min = world.clearances().fold(f64::INFINITY, f64::min);
        let wall = world.wall_clearance();
        self.samples.push(TruthSample {
            t: world.time(),
            x: pose.position.re,
            y: pose.position.im,
            heading: pose.heading,
            wheel_speeds: world.wheel_speeds(),
            min_clearance: min.is_finite().then_some(min),
            wall_clearance: wall.is_finite().then_some(wall),
            contact: min < 0.0 || wall < 0.0,
            obstacles: (0..world.obstacle_count())
                .map(|k| {
                    let p = world.obstacle_position(k, world.time());
                    [p.re, p.im]
                })
                .collect(),
        });
        let t = world.truth();
        self.summary = TruthSummary {
            duration: world.time(),
            min_obstacle_clearance: t.min_obstacle_clearance.is_finite().then_some(t.min_obstacle_clearance),
            min_wall_clearance: t.min_wall_clearance.is_finite().then_some(t.min_wall_clearance),
            first_contact: t.first_contact,
            contact: t.contact,
            path_length: t.path_length,
            final_position: [pose.position.re, pose.position.im],
            peak_wheel_speed: t.peak_wheel_speed,
        };
    }

    /// Write as JSON (`.json`) or CSV.
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
        if path.extension().is_some_and(|e| e == "json") {
            serde_json::to_writer_pretty(&mut f, self)?;
        } else {
            let n = self.samples.first().map_or(0, |s| s.obstacles.len());
            write!(f, "t,x,y,heading,v_left,v_right,min_clearance,wall_clearance,contact")?;
            for k in 0..n {
                write!(f, ",o{k}x,o{k}y")?;
            }
            writeln!(f)?;
            let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6}"));
            for s in &self.samples {
                write!(
                    f,
                    "{:.4},{:.6},{:.6},{:.6},{:.6},{:.6},{},{},{}",
                    s.t,
                    s.x,
                    s.y,
                    s.heading,
                    s.wheel_speeds[0],
                    s.wheel_speeds[1],
                    opt(s.min_clearance),
                    opt(s.wall_clearance),
                    u8::from(s.contact)
                )?;
                for o in &s.obstacles {
                    write!(f, ",{:.6},{:.6}", o[0], o[1])?;
                }
                writeln!(f)?;
            }
        }
        f.flush()
    }
}
