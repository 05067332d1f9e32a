//! Maze layouts (placeholder type until the maze module lands; see issue #2).

/// A maze layout with its cell size.
#[derive(Debug, Clone, PartialEq)]
pub struct Maze;
