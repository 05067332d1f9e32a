//! The point mass: walls stop it, it stays finite, resets within the noise, and its constants
//! give the intended reach (a 4 m cell in about 5–10 control steps).

use envs::api::Robot;
use envs::maze::{Maze, MazeLayout};
use envs::point::{PointMass, PointParams};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Slack for the push-out, metres.
const CONTACT_TOLERANCE_M: f32 = 1e-4;

fn ball_in(layout: MazeLayout) -> (Maze, PointMass) {
    let maze = Maze::new(layout);
    let ball =
        PointMass::new(PointParams::default(), &maze.walls()).expect("default params are valid");
    (maze, ball)
}

/// Distance from `xy` to the nearest wall box (0 when inside one).
fn clearance(maze: &Maze, xy: [f32; 2]) -> f32 {
    maze.walls()
        .iter()
        .map(|b| {
            let dx = ((xy[0] - b.center[0]).abs() - b.half_extents[0]).max(0.0);
            let dy = ((xy[1] - b.center[1]).abs() - b.half_extents[1]).max(0.0);
            (dx * dx + dy * dy).sqrt()
        })
        .fold(f32::INFINITY, f32::min)
}

#[test]
fn the_point_mass_cannot_pass_through_a_wall() {
    let (maze, mut ball) = ball_in(MazeLayout::U);
    let radius = ball.params().radius_m;
    // From the start, push into the inner wall of the U (its face is at y = 2) for 200 steps.
    for _ in 0..200 {
        ball.step(&[0.0, 1.0]);
        assert!(
            ball.xy()[1] <= 2.0 - radius + CONTACT_TOLERANCE_M,
            "{:?}",
            ball.xy()
        );
    }
    assert!(
        ball.velocity()[1].abs() < 1e-3,
        "the inward velocity is cancelled"
    );
    // Then push left into the outer wall (face at x = −2) and diagonally into the corner.
    for action in [[-1.0, 0.0], [-1.0, -1.0]] {
        for _ in 0..200 {
            ball.step(&action);
            assert!(
                clearance(&maze, ball.xy()) >= radius - CONTACT_TOLERANCE_M,
                "{:?}",
                ball.xy()
            );
        }
    }
    let corner = [-2.0 + radius, -2.0 + radius];
    assert!(
        (ball.xy()[0] - corner[0]).abs() < 1e-3 && (ball.xy()[1] - corner[1]).abs() < 1e-3,
        "{:?}",
        ball.xy()
    );
}

#[test]
fn a_ball_placed_inside_a_wall_is_pushed_out_through_the_nearest_face() {
    let (_, mut ball) = ball_in(MazeLayout::U);
    // Inner wall spans y ∈ [2, 6]; at y = 2.3 the nearest face is y = 2.
    ball.set_state([0.0, 2.3], [0.0, 0.0]);
    ball.step(&[0.0, 0.0]);
    assert!(
        (ball.xy()[1] - (2.0 - ball.params().radius_m)).abs() < 1e-4,
        "{:?}",
        ball.xy()
    );
}

#[test]
fn ten_thousand_random_steps_stay_finite_and_out_of_the_walls() {
    for layout in MazeLayout::ALL {
        let (maze, mut ball) = ball_in(layout);
        let radius = ball.params().radius_m;
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        let mut obs = [0.0f32; 4];
        for _ in 0..10_000 {
            let action = [rng.random_range(-1.0..=1.0), rng.random_range(-1.0..=1.0)];
            ball.step(&action);
            ball.write_obs(&mut obs);
            assert!(obs.iter().all(|v| v.is_finite()), "{layout:?}: {obs:?}");
            assert!(
                clearance(&maze, ball.xy()) >= radius - CONTACT_TOLERANCE_M,
                "{layout:?}: {:?}",
                ball.xy()
            );
            let speed = (obs[2] * obs[2] + obs[3] * obs[3]).sqrt();
            assert!(
                speed <= ball.params().max_speed_m_per_s + 1e-4,
                "{layout:?}: speed {speed}"
            );
        }
    }
}

#[test]
fn reset_noise_stays_within_a_tenth_of_a_metre() {
    let (_, mut ball) = ball_in(MazeLayout::U);
    let mut max_abs = 0.0f32;
    for seed in 0..500 {
        ball.step(&[1.0, 1.0]);
        ball.reset(&mut Pcg64Mcg::seed_from_u64(seed));
        let [x, y] = ball.xy();
        assert!(x.abs() <= 0.1 && y.abs() <= 0.1, "seed {seed}: ({x}, {y})");
        assert_eq!(ball.velocity(), [0.0, 0.0]);
        max_abs = max_abs.max(x.abs()).max(y.abs());
    }
    assert!(max_abs > 0.05, "the noise is actually applied");
}

#[test]
fn observation_is_position_then_velocity() {
    let (_, mut ball) = ball_in(MazeLayout::U);
    ball.set_state([1.0, -0.5], [0.25, 0.75]);
    let mut obs = [0.0f32; 4];
    ball.write_obs(&mut obs);
    assert_eq!(obs, [1.0, -0.5, 0.25, 0.75]);
    assert_eq!(
        (ball.obs_dim(), ball.action_dim(), ball.action_bound()),
        (4, 2, 1.0)
    );
    assert_eq!(ball.torso_z(), None);
    assert!((ball.control_dt_secs() - 0.2).abs() < 1e-9);
}

#[test]
fn full_force_crosses_a_four_metre_cell_in_five_to_ten_control_steps() {
    let (_, mut ball) = ball_in(MazeLayout::U);
    let n_steps = (1..=50).find(|_| {
        ball.step(&[1.0, 0.0]);
        ball.xy()[0] >= 4.0
    });
    let n_steps = n_steps.expect("reaches x = 4 within 50 steps");
    assert!((5..=10).contains(&n_steps), "took {n_steps} steps");
}

#[test]
fn invalid_point_params_are_rejected() {
    let walls = Maze::new(MazeLayout::U).walls();
    let bad = [
        PointParams {
            n_substeps: 0,
            ..PointParams::default()
        },
        PointParams {
            mass_kg: 0.0,
            ..PointParams::default()
        },
        PointParams {
            radius_m: 0.01,
            ..PointParams::default()
        },
        PointParams {
            damping_n_s_per_m: 100.0,
            ..PointParams::default()
        },
        PointParams {
            reset_noise_m: f32::NAN,
            ..PointParams::default()
        },
    ];
    for params in bad {
        assert!(PointMass::new(params, &walls).is_err(), "{params:?}");
    }
}
