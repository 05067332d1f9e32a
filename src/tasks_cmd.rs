//! `asi tasks [NAME] [--json]`: the registered task names, or what one task is — its maze (map,
//! cell size, start, test goal, goal box), episode length, observation and action sizes and
//! reward — as text for people or JSON for analysis scripts (`scripts/maze_path.py` reads the
//! map to measure how far along a maze a position is).

use anyhow::Context;
use clap::Args;
use envs::registry::{self, EnvOptions, Task};
use envs::{Maze, Variant};
use serde_json::{json, Value};

#[derive(Debug, Args)]
pub struct TasksArgs {
    /// Describe this task (see the list without it): its maze map, start, goals, episode
    /// length, observation and action sizes.
    pub name: Option<String>,
    /// Print the description as one JSON object (keys as in the text form; `maze` is null for
    /// tasks without one). Needs NAME.
    #[arg(long, requires = "name")]
    pub json: bool,
}

pub fn run(args: &TasksArgs) -> anyhow::Result<()> {
    let Some(name) = &args.name else {
        for name in registry::task_names() {
            println!("{name}");
        }
        return Ok(());
    };
    let description = describe(name)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&description)?);
    } else {
        print!("{}", as_text(&description));
    }
    Ok(())
}

/// The description of the task `name` as a JSON object; the unknown-task error lists the names.
pub fn describe(name: &str) -> anyhow::Result<Value> {
    let task = registry::parse_task(name)?;
    let env = registry::make(name).with_context(|| format!("building task {name}"))?;
    let spec = env.spec();
    let reward = registry::sparse_reward(name, EnvOptions::default())?;
    let (kind, variant) = match task {
        Task::Maze(id) => (
            format!("{:?} robot in the {:?} maze", id.robot, id.layout),
            match id.variant {
                Variant::Train => "train: goals sampled over the free cells of the goal box; success does not end the episode",
                Variant::Test => "test: the fixed evaluation goal; success ends the episode",
            },
        ),
        Task::HalfCheetahHurdle(variant) => (
            "HalfCheetah robot before hurdles".to_string(),
            match variant {
                Variant::Train => "train: success does not end the episode",
                Variant::Test => "test: success ends the episode",
            },
        ),
    };
    Ok(json!({
        "name": name,
        "kind": kind,
        "variant": variant,
        "episode_steps": spec.max_steps,
        "control_dt_secs": spec.control_dt_secs,
        "obs_dim": spec.obs_dim,
        "action_dim": spec.action_dim,
        "action_low": spec.action_low,
        "action_high": spec.action_high,
        "goal_dim": spec.goal_dim,
        "success_threshold": spec.success_threshold,
        "step_penalty": reward.step_penalty,
        "fall_penalty": reward.fall_penalty,
        "maze": env.maze().map(maze_json),
    }))
}

fn maze_json(maze: &Maze) -> Value {
    let robot = maze.robot_cell();
    let goal = maze.goal_cell();
    let goal_box = maze.goal_box();
    let bounds = maze.world_bounds();
    json!({
        "rows": maze.rows(),
        "cell_size_m": maze.cell_size_m(),
        "robot_cell": [robot.i, robot.j],
        "goal_cell": [goal.i, goal.j],
        "test_goal": maze.test_goal(),
        "goal_box": [goal_box.low, goal_box.high],
        "world_bounds": [bounds.low, bounds.high],
        "free_cells": maze.free_cells().count(),
        "start_to_goal_m": maze.path_distance(robot, goal).map(|d| d as f32 * maze.cell_size_m()),
    })
}

/// Keys of the text form, in the order printed (JSON objects sort their keys).
const TEXT_ORDER: [&str; 14] = [
    "name",
    "kind",
    "variant",
    "episode_steps",
    "control_dt_secs",
    "obs_dim",
    "action_dim",
    "action_low",
    "action_high",
    "goal_dim",
    "success_threshold",
    "step_penalty",
    "fall_penalty",
    "maze",
];

/// Keys of the maze entry of the text form, in the order printed.
const MAZE_TEXT_ORDER: [&str; 9] = [
    "rows",
    "cell_size_m",
    "robot_cell",
    "goal_cell",
    "test_goal",
    "start_to_goal_m",
    "goal_box",
    "world_bounds",
    "free_cells",
];

/// The text form: one `key: value` line per entry, the maze map drawn as rows.
fn as_text(description: &Value) -> String {
    let mut out = String::new();
    for key in TEXT_ORDER {
        match &description[key] {
            maze @ Value::Object(_) => {
                out.push_str("maze:\n");
                for key in MAZE_TEXT_ORDER {
                    match &maze[key] {
                        Value::Array(rows) if key == "rows" => {
                            out.push_str("  map (# wall, . free, S start at (0, 0), G test goal; y grows downward):\n");
                            for row in rows {
                                out.push_str(&format!(
                                    "    {}\n",
                                    row.as_str().unwrap_or_default()
                                ));
                            }
                        }
                        value => out.push_str(&format!("  {key}: {value}\n")),
                    }
                }
            }
            Value::String(text) => out.push_str(&format!("{key}: {text}\n")),
            Value::Number(n) if n.is_f64() => {
                out.push_str(&format!("{key}: {}\n", n.as_f64().map_or(0.0, round6)));
            }
            value => out.push_str(&format!("{key}: {value}\n")),
        }
    }
    out
}

/// `x` rounded to 6 significant decimals, so an f32 widened to f64 prints as written (0.2, not
/// 0.19999999552965164).
fn round6(x: f64) -> f64 {
    (x * 1e6).round() / 1e6
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn antmaze_u_is_described_with_its_map_start_and_goal() {
        let d = describe("antmaze-u").unwrap();
        assert_eq!(d["episode_steps"], 500);
        assert_eq!(d["obs_dim"], 29);
        assert_eq!(d["action_dim"], 8);
        let maze = &d["maze"];
        assert_eq!(
            maze["rows"],
            json!(["#####", "#S..#", "###.#", "#G..#", "#####"])
        );
        assert_eq!(maze["cell_size_m"], 4.0);
        assert_eq!(maze["robot_cell"], json!([1, 1]));
        assert_eq!(maze["test_goal"], json!([0.0, 8.0]));
        assert_eq!(maze["start_to_goal_m"], 24.0);
        assert_eq!(maze["free_cells"], 7);
        let text = as_text(&d);
        assert!(text.contains("    #G..#\n"), "{text}");
        assert!(text.starts_with("name: antmaze-u\n"), "{text}");
        assert!(text.contains("control_dt_secs: 0.2\n"), "{text}");
        assert!(text.contains("episode_steps: 500\n"), "{text}");
    }

    #[test]
    fn the_cheetah_has_no_maze_and_unknown_names_list_the_known_ones() {
        let d = describe("halfcheetah-hurdle").unwrap();
        assert_eq!(d["maze"], Value::Null);
        assert_eq!(d["episode_steps"], 1000);
        let err = describe("antmaze-x").unwrap_err().to_string();
        assert!(
            err.contains("antmaze-u") && err.contains("antmaze-x"),
            "{err}"
        );
    }
}
