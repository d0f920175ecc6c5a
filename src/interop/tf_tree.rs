//! What a listener saw of another program's tf tree, and the two questions easyhec asks of it
//! before it publishes an edge: does the child frame already have a parent (tf allows one), and
//! what fixed transform links the camera's root link to its optical frame.
//!
//! Pure data: the ROS 2 listener ([`crate::ros2`]) fills it, tests fill it by hand.

use std::collections::BTreeMap;

use nalgebra::Isometry3;

use crate::error::{Error, Result};

use super::TfEdge;

/// The topic an edge was seen on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TfSource {
    /// `/tf`: moving frames, republished at a rate.
    Dynamic,
    /// `/tf_static`: fixed frames, latched (transient local).
    Static,
}

impl TfSource {
    /// The topic's name, for messages.
    pub fn topic(self) -> &'static str {
        match self {
            TfSource::Dynamic => "/tf",
            TfSource::Static => "/tf_static",
        }
    }
}

/// Edges keyed by child frame; the last one seen for a child wins, as in tf2's buffer.
#[derive(Clone, Debug, Default)]
pub struct TfTree {
    by_child: BTreeMap<String, (TfEdge, TfSource)>,
}

/// Longest chain of fixed edges followed from a camera's root link to its optical frame.
const MAX_CHAIN: usize = 16;

impl TfTree {
    /// Records an edge.
    pub fn insert(&mut self, edge: TfEdge, source: TfSource) {
        self.by_child.insert(edge.child.clone(), (edge, source));
    }

    /// Number of child frames seen.
    pub fn len(&self) -> usize {
        self.by_child.len()
    }

    /// Whether nothing was seen.
    pub fn is_empty(&self) -> bool {
        self.by_child.is_empty()
    }

    /// The parent `child` already has, and the topic it came on.
    pub fn parent_of(&self, child: &str) -> Option<(&str, TfSource)> {
        self.by_child
            .get(child)
            .map(|(e, s)| (e.parent.as_str(), *s))
    }

    /// Refuses `edge` when its child already has a parent, or when its parent hangs below its
    /// child (a loop). Either would leave tf with a frame of two parents.
    pub fn check_can_add(&self, edge: &TfEdge) -> Result<()> {
        if let Some((parent, source)) = self.parent_of(&edge.child) {
            return Err(Error::Usage(format!(
                "child frame {child:?} already has the parent {parent:?} on {topic}, and a tf frame has one parent; \
                 allowed: a frame with no parent, such as the camera's root link given with its optical_from_child (docs/ros2.md)",
                child = edge.child,
                topic = source.topic(),
            )));
        }
        // Walk up from the parent; a loop in what others published ends the walk too.
        let mut frame = edge.parent.as_str();
        let mut visited = std::collections::BTreeSet::new();
        while visited.insert(frame) {
            if frame == edge.child {
                return Err(Error::Usage(format!(
                    "parent frame {:?} lies below child frame {:?} in the tf tree; allowed: a parent that is not a descendant of the child",
                    edge.parent, edge.child
                )));
            }
            match self.parent_of(frame) {
                Some((p, _)) => frame = p,
                None => break,
            }
        }
        Ok(())
    }

    /// `ancestor_from_descendant` through fixed (`/tf_static`) edges only: a camera driver's
    /// root link to its optical frame. `None` when no such chain of at most [`MAX_CHAIN`] edges
    /// was seen.
    pub fn static_chain(&self, ancestor: &str, descendant: &str) -> Option<Isometry3<f64>> {
        let mut pose = Isometry3::identity();
        let mut frame = descendant;
        for _ in 0..MAX_CHAIN {
            if frame == ancestor {
                return Some(pose);
            }
            let (edge, source) = self.by_child.get(frame)?;
            if *source != TfSource::Static {
                return None;
            }
            pose = edge.parent_from_child * pose;
            frame = &edge.parent;
        }
        (frame == ancestor).then_some(pose)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{exp_se3, Twist};

    fn edge(parent: &str, child: &str, twist: Twist) -> TfEdge {
        TfEdge {
            parent: parent.into(),
            child: child.into(),
            parent_from_child: exp_se3(&twist),
        }
    }

    /// A RealSense-like driver tree: camera_link → camera_color_frame → camera_color_optical_frame.
    fn driver_tree() -> TfTree {
        let mut tree = TfTree::default();
        tree.insert(
            edge(
                "camera_link",
                "camera_color_frame",
                Twist::new(0.0, 0.015, 0.0, 0.0, 0.0, 0.01),
            ),
            TfSource::Static,
        );
        tree.insert(
            edge(
                "camera_color_frame",
                "camera_color_optical_frame",
                Twist::new(0.0, 0.0, 0.0, -1.2092, 1.2092, -1.2092),
            ),
            TfSource::Static,
        );
        tree.insert(
            edge("world", "tool0", Twist::new(0.1, 0.2, 0.3, 0.0, 0.0, 0.0)),
            TfSource::Dynamic,
        );
        tree
    }

    #[test]
    fn a_frame_with_a_parent_or_a_loop_is_refused() {
        let tree = driver_tree();
        let id = Twist::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let msg = tree
            .check_can_add(&edge("base", "camera_color_optical_frame", id))
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("\"camera_color_frame\"") && msg.contains("/tf_static"),
            "{msg}"
        );
        assert!(tree
            .check_can_add(&edge("base", "tool0", id))
            .unwrap_err()
            .to_string()
            .contains("/tf"));
        assert!(tree.check_can_add(&edge("base", "camera_link", id)).is_ok());
        let looped = tree.check_can_add(&edge("camera_color_frame", "camera_link", id));
        assert!(looped.unwrap_err().to_string().contains("below"));
    }

    #[test]
    fn the_static_chain_composes_root_link_to_optical_frame() {
        let tree = driver_tree();
        let chain = tree
            .static_chain("camera_link", "camera_color_optical_frame")
            .unwrap();
        let a = tree.by_child["camera_color_frame"].0.parent_from_child;
        let b = tree.by_child["camera_color_optical_frame"]
            .0
            .parent_from_child;
        assert!(((a * b).to_homogeneous() - chain.to_homogeneous()).norm() < 1e-15);
        assert!(tree
            .static_chain("world", "camera_color_optical_frame")
            .is_none());
        assert!(
            tree.static_chain("world", "tool0").is_none(),
            "/tf edges move"
        );
    }
}
