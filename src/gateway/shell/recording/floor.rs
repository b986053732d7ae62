//! Foxglove's primitives laid on the floor: poses, discs, lines, arrows and names, in the
//! floor's frame, in metres.

use foxglove::messages::{
    ArrowPrimitive, Color, CylinderPrimitive, LinePrimitive, Pose, Quaternion, TextPrimitive, Vector3,
};

/// The frame every pose and entity is in: the floor's, in metres.
pub(super) const FRAME: &str = "floor";

/// A pose on the floor at height `z`, turned `heading` rad about the vertical.
pub(super) fn floor_pose(x: f64, y: f64, heading: f64, z: f64) -> Pose {
    Pose {
        position: Some(Vector3 { x, y, z }),
        orientation: Some(Quaternion { x: 0.0, y: 0.0, z: (heading / 2.0).sin(), w: (heading / 2.0).cos() }),
    }
}

pub(super) fn rgba([r, g, b, a]: [f64; 4]) -> Color {
    Color { r, g, b, a }
}

/// A disc (a flat cylinder) of radius `r` and height `h` standing on the floor at `(x, y)`.
pub(super) fn disc(x: f64, y: f64, r: f64, h: f64, color: [f64; 4]) -> CylinderPrimitive {
    CylinderPrimitive {
        pose: Some(floor_pose(x, y, 0.0, h / 2.0)),
        size: Some(Vector3 { x: 2.0 * r, y: 2.0 * r, z: h }),
        bottom_scale: 1.0,
        top_scale: 1.0,
        color: Some(rgba(color)),
    }
}

/// A line on the floor through `points` (a loop back to the first when `closed`).
pub(super) fn floor_line(points: &[[f64; 2]], closed: bool, thickness: f64, color: [f64; 4]) -> LinePrimitive {
    use foxglove::messages::line_primitive::Type;
    LinePrimitive {
        r#type: if closed { Type::LineLoop } else { Type::LineStrip } as i32,
        pose: Some(floor_pose(0.0, 0.0, 0.0, 0.0)),
        thickness,
        scale_invariant: false,
        points: points.iter().map(|&[x, y]| foxglove::messages::Point3 { x, y, z: 0.0 }).collect(),
        color: Some(rgba(color)),
        colors: Vec::new(),
        indices: Vec::new(),
    }
}

/// A fleet's navigating vehicles and scripted vehicles, and their goals (the robot is blue).
pub(super) const VEHICLE_COLOR: [f64; 4] = [0.1, 0.6, 0.6, 0.9];
pub(super) const SCRIPTED_COLOR: [f64; 4] = [0.6, 0.3, 0.8, 0.9];

/// A vehicle's heading: an arrow from its centre to its rim.
pub(super) fn heading_arrow(x: f64, y: f64, heading: f64, radius: f64) -> ArrowPrimitive {
    ArrowPrimitive {
        pose: Some(floor_pose(x, y, heading, 0.06)),
        shaft_length: radius,
        shaft_diameter: 0.008,
        head_length: 0.02,
        head_diameter: 0.025,
        color: Some(rgba([1.0, 1.0, 1.0, 1.0])),
    }
}

/// A name over a vehicle.
pub(super) fn floor_text(x: f64, y: f64, text: &str) -> TextPrimitive {
    TextPrimitive {
        pose: Some(floor_pose(x, y, 0.0, 0.15)),
        billboard: true,
        font_size: 14.0,
        scale_invariant: true,
        color: Some(rgba([0.1, 0.1, 0.1, 1.0])),
        text: text.into(),
    }
}
