//! People: obstacles that walk to goals of their own and avoid each other, the walls and the
//! furniture (`behaviour = "orca"` or `"social_force"` on `[[obstacles]]` and `[crowd]`),
//! where a scripted obstacle (`behaviour = "straight"`, the default) follows its `motion`
//! whatever is in its way. The robot is invisible to them, as in CrowdNav's setting, unless
//! they see it (`sees_robot`).
//!
//! What the keys mean, and what is refused at load, naming the key.

use serde::Deserialize;

use super::{validate_length, validate_point, ObstacleSpec, Refused, MAX_POINTS, MAX_SPEED_M_S};
use crate::Point;

/// How an obstacle moves.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Behaviour {
    /// Along its `motion`, through whatever is in its way.
    #[default]
    Straight,
    /// As a person avoiding the others by optimal reciprocal collision avoidance.
    Orca,
    /// As a person pushed by social forces (Helbing and Molnár).
    SocialForce,
}

impl Behaviour {
    /// Whether it walks to goals and avoids others.
    pub fn walks(self) -> bool {
        self != Behaviour::Straight
    }
}

/// What a person does at their last goal.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OnArrival {
    /// Stands there (still avoiding others).
    #[default]
    Stop,
    /// Walks on to a new goal drawn from the scenario's seed, anywhere in the area every
    /// person's start and goals span, clear of the furniture (as CrowdNav++ does).
    NewGoal,
}

/// When the simulator walks the people who do not see the robot (`people_walk`; those who
/// see it always walk as the world runs, since where they go depends on it).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PeopleWalk {
    /// Before the run, for its whole time limit and 30 s beyond: the world knows each
    /// person's fastest leg, and its judge bounds the person's speed by it.
    #[default]
    Ahead,
    /// A step at a time as the world runs, only as far as the run goes: the same ways, but
    /// the judge bounds each person's speed by their cap (the fastest legs are not yet
    /// walked), so it samples a little more finely and the runs are alike in distribution,
    /// not in their bits. Faster where runs end well before their time limit.
    AsNeeded,
}

/// The most a person walks, as a multiple of its preferred speed, when avoiding others:
/// Helbing and Molnár's cap.
pub const SPEED_CAP: f64 = 1.3;
/// The longest group name.
const MAX_GROUP_NAME: usize = 32;

/// A person's walk, as checked at load.
#[derive(Debug, Clone, PartialEq)]
pub struct Walk {
    pub behaviour: Behaviour,
    pub goals: Vec<Point>,
    pub preferred_speed: f64,
    pub on_arrival: OnArrival,
    pub sees_robot: bool,
}

impl ObstacleSpec {
    /// The fastest it ever moves, m/s: its motion's, or a person's cap.
    pub fn top_speed(&self) -> f64 {
        if self.behaviour.walks() {
            return self.preferred_speed.unwrap_or(0.0) * SPEED_CAP;
        }
        match &self.motion {
            super::Motion::Stationary => 0.0,
            super::Motion::Constant { velocity } => velocity[0].hypot(velocity[1]),
            super::Motion::Waypoints { speed, .. } => *speed,
        }
    }

    /// The person's walk, for an obstacle that walks (once the scenario has been validated at load).
    pub fn walk(&self) -> Option<Walk> {
        self.behaviour.walks().then(|| Walk {
            behaviour: self.behaviour,
            goals: self.goal.iter().chain(&self.goals).map(|&g| super::point(g)).collect(),
            preferred_speed: self.preferred_speed.unwrap_or(0.0),
            on_arrival: self.on_arrival,
            sees_robot: self.sees_robot,
        })
    }

    /// The keys of a person who walks: a goal (or goals), a preferred speed, no motion; and
    /// none of them on an obstacle that does not walk.
    pub(crate) fn validate_walk(&self, key: &str) -> Refused {
        let refuse = |k: &str, why: &str| Err((format!("{key}.{k}"), why.to_string()));
        if !self.behaviour.walks() {
            let person = "is for a person who walks: set behaviour = \"orca\" or \"social_force\"";
            return match () {
                _ if self.goal.is_some() => refuse("goal", person),
                _ if !self.goals.is_empty() => refuse("goals", person),
                _ if self.preferred_speed.is_some() => refuse("preferred_speed", person),
                _ if self.on_arrival != OnArrival::Stop => refuse("on_arrival", person),
                _ if self.sees_robot => refuse("sees_robot", person),
                _ if self.group.is_some() => refuse("group", person),
                _ => Ok(()),
            };
        }
        if self.motion != super::Motion::Stationary {
            return refuse("motion", "a person walks to their goals: leave motion out");
        }
        match (self.goal, self.goals.len()) {
            (None, 0) => return refuse("goal", "a person walks to a goal: set goal = [x, y] (or goals)"),
            (Some(_), n) if n > 0 => return refuse("goals", "give goal or goals, not both"),
            (_, n) if n > MAX_POINTS => {
                return Err((format!("{key}.goals"), format!("{n} goals: at most {MAX_POINTS}")));
            }
            _ => {}
        }
        if let Some(g) = self.goal {
            validate_point(&format!("{key}.goal"), g)?;
        }
        for (i, &g) in self.goals.iter().enumerate() {
            validate_point(&format!("{key}.goals[{i}]"), g)?;
        }
        if self.group.as_ref().is_some_and(|g| g.is_empty() || g.len() > MAX_GROUP_NAME) {
            return refuse("group", "a group's name is 1-32 characters");
        }
        match self.preferred_speed {
            None => refuse("preferred_speed", "a person walks at a preferred speed: set it, m/s"),
            Some(v) => validate_length(&format!("{key}.preferred_speed"), v, MAX_SPEED_M_S),
        }
    }
}

impl super::SimScenario {
    /// A group walks together: at least two people.
    pub(super) fn validate_groups(&self) -> Refused {
        for (i, o) in self.obstacles.iter().enumerate() {
            let Some(name) = &o.group else { continue };
            if self.obstacles.iter().filter(|p| p.group.as_ref() == Some(name)).count() < 2 {
                let why = format!("{name:?} has no other member: a group walks together");
                return Err((format!("obstacles[{i}].group"), why));
            }
        }
        Ok(())
    }
}
