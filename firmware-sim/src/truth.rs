//! The world's truth over a run: what tests judge the gateway by, never its own belief.
//!
//! Written at exit with `--truth FILE`: JSON (`.json`) with a summary and the samples, or
//! CSV (any other extension) with one row per sample:
//! `t,x,y,heading,v_left,v_right,min_clearance,wall_clearance,contact,o0x,o0y,o1x,...`
//! (metres, radians, m/s; `contact` 0/1), then for a fleet each other vehicle's
//! `NAME_x,NAME_y,NAME_heading`. Samples are taken every 20 ms of real time.

use serde::Serialize;
use std::io::Write as _;
use std::path::Path;

use crate::world::fleet::{Fleet, VehicleContact};
use crate::world::{Contact, World};

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
    /// A fleet's other vehicles (the robot is the sample's own pose).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub vehicles: Vec<VehicleSample>,
}

/// One of a fleet's other vehicles at a sample.
#[derive(Debug, Clone, Serialize)]
pub struct VehicleSample {
    pub name: String,
    pub x: f64,
    pub y: f64,
    pub heading: f64,
    pub wheel_speeds: [f64; 2],
}

/// Each vehicle of a fleet over the run, the robot first.
#[derive(Debug, Clone, Serialize)]
pub struct VehicleTruth {
    pub name: String,
    pub final_position: [f64; 2],
    pub path_length: f64,
    /// Its first contact with an obstacle, a person or a wall.
    pub contact: Option<Contact>,
    /// Its first contact with another vehicle (`with`: the other's index, 0 the robot).
    pub vehicle_contact: Option<VehicleContact>,
    /// Its smallest gap to another vehicle's footprint, m.
    pub min_vehicle_gap: f64,
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
    /// A fleet's vehicles, the robot first (empty for the robot alone).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub vehicles: Vec<VehicleTruth>,
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
            vehicles: Vec::new(),
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
            vehicles: Vec::new(),
        };
    }

    /// Take a sample of a fleet now: the robot's as [`Self::record`], and for more than one
    /// vehicle every other's pose and each one's contacts. `names`: the vehicles', the robot
    /// first.
    pub fn record_fleet(&mut self, fleet: &Fleet, names: &[String]) {
        self.record(fleet.world(0));
        if fleet.len() < 2 {
            return;
        }
        let sample = self.samples.last_mut().expect("just recorded");
        for (k, name) in names.iter().enumerate().take(fleet.len()).skip(1) {
            let w = fleet.world(k);
            let pose = w.pose();
            let (x, y, heading) = (pose.position.re, pose.position.im, pose.heading);
            sample.vehicles.push(VehicleSample { name: name.clone(), x, y, heading, wheel_speeds: w.wheel_speeds() });
        }
        self.summary.vehicles = names
            .iter()
            .enumerate()
            .take(fleet.len())
            .map(|(k, name)| {
                let (w, truth) = (fleet.world(k), fleet.world(k).truth());
                let at = w.pose().position;
                VehicleTruth {
                    name: name.clone(),
                    final_position: [at.re, at.im],
                    path_length: truth.path_length,
                    contact: truth.contact,
                    vehicle_contact: fleet.vehicle_contact(k),
                    min_vehicle_gap: fleet.min_vehicle_gap(k),
                }
            })
            .collect();
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
            for v in self.samples.first().map_or(&[][..], |s| &s.vehicles[..]) {
                write!(f, ",{0}_x,{0}_y,{0}_heading", v.name)?;
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
                for v in &s.vehicles {
                    write!(f, ",{:.6},{:.6},{:.6}", v.x, v.y, v.heading)?;
                }
                writeln!(f)?;
            }
        }
        f.flush()
    }
}
