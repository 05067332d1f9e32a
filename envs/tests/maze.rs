//! Maze layouts against the digest's maps (§9.2): walls, start and goal cells, goal box, cell
//! lookup, BFS path distances, the far-goal rule and training-goal sampling.

use envs::api::EnvError;
use envs::maze::{Cell, Maze, MazeLayout, Rect};
use proptest::prelude::*;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

/// Free cells of each layout, typed from the digest's pictures (row, column).
fn expected_free_cells(layout: MazeLayout) -> Vec<(usize, usize)> {
    let rows = |spec: &[(usize, &[usize])]| -> Vec<(usize, usize)> {
        spec.iter()
            .flat_map(|&(i, js)| js.iter().map(move |&j| (i, j)))
            .collect()
    };
    match layout {
        MazeLayout::U => rows(&[(1, &[1, 2, 3]), (2, &[3]), (3, &[1, 2, 3])]),
        MazeLayout::S => rows(&[
            (1, &[1, 2, 3, 4, 5]),
            (2, &[5]),
            (3, &[1, 2, 3, 4, 5]),
            (4, &[1]),
            (5, &[1, 2, 3, 4, 5]),
        ]),
        MazeLayout::W => rows(&[
            (1, &[1, 2, 3, 4, 5]),
            (2, &[1, 5]),
            (3, &[3, 4, 5]),
            (4, &[1, 5]),
            (5, &[1, 2, 3, 4, 5]),
        ]),
        MazeLayout::FourRooms => {
            let room_row: &[usize] = &[1, 2, 3, 4, 6, 7, 8, 9];
            let open_row: &[usize] = &[1, 2, 3, 4, 5, 6, 7, 8, 9];
            rows(&[
                (1, room_row),
                (2, room_row),
                (3, open_row),
                (4, room_row),
                (5, &[2, 8]),
                (6, room_row),
                (7, room_row),
                (8, open_row),
                (9, room_row),
            ])
        }
    }
}

#[test]
fn walls_are_exactly_where_each_layout_says() {
    for layout in MazeLayout::ALL {
        let maze = Maze::new(layout);
        let expected = expected_free_cells(layout);
        for i in 0..maze.n_rows() {
            for j in 0..maze.n_cols() {
                let free = expected.contains(&(i, j));
                assert_eq!(
                    maze.is_free(Cell::new(i, j)),
                    free,
                    "{layout:?} cell ({i}, {j})"
                );
                assert_eq!(
                    maze.is_wall(Cell::new(i, j)),
                    !free,
                    "{layout:?} cell ({i}, {j})"
                );
            }
        }
        assert_eq!(maze.free_cells().count(), expected.len(), "{layout:?}");
    }
}

#[test]
fn grid_sizes_cell_sizes_and_episode_lengths_match_the_digest() {
    let expected = [
        (MazeLayout::U, 5, 4.0, 500),
        (MazeLayout::S, 7, 4.0, 1000),
        (MazeLayout::W, 7, 4.0, 1000),
        (MazeLayout::FourRooms, 11, 2.0, 1000),
    ];
    for (layout, n, s, t) in expected {
        let maze = Maze::new(layout);
        assert_eq!((maze.n_rows(), maze.n_cols()), (n, n), "{layout:?}");
        assert_eq!(maze.cell_size_m(), s, "{layout:?}");
        assert_eq!(maze.max_steps(), t, "{layout:?}");
        assert_eq!(maze.layout(), Some(layout));
    }
}

#[test]
fn start_and_goal_cells_and_test_goals_match_the_digest() {
    let expected = [
        (MazeLayout::U, (1, 1), (3, 1), [0.0, 8.0]),
        (MazeLayout::S, (1, 1), (5, 5), [16.0, 16.0]),
        (MazeLayout::W, (2, 1), (4, 1), [0.0, 8.0]),
        (MazeLayout::FourRooms, (2, 2), (9, 9), [14.0, 14.0]),
    ];
    for (layout, robot, goal, test_goal) in expected {
        let maze = Maze::new(layout);
        assert_eq!(maze.robot_cell(), Cell::new(robot.0, robot.1), "{layout:?}");
        assert_eq!(maze.goal_cell(), Cell::new(goal.0, goal.1), "{layout:?}");
        assert_eq!(maze.test_goal(), test_goal, "{layout:?}");
        assert_eq!(
            maze.cell_center(maze.robot_cell()),
            [0.0, 0.0],
            "{layout:?}: start at the origin"
        );
    }
}

#[test]
fn goal_boxes_match_the_digest() {
    let expected = [
        (MazeLayout::U, [-2.0, -2.0], [10.0, 10.0]),
        (MazeLayout::S, [-2.0, -2.0], [18.0, 18.0]),
        (MazeLayout::W, [-2.0, -6.0], [18.0, 14.0]),
        (MazeLayout::FourRooms, [-3.0, -3.0], [15.0, 15.0]),
    ];
    for (layout, low, high) in expected {
        assert_eq!(
            Maze::new(layout).goal_box(),
            Rect { low, high },
            "{layout:?}"
        );
    }
}

#[test]
fn wall_boxes_are_half_a_cell_tall_and_centred_on_wall_cells() {
    let maze = Maze::new(MazeLayout::U);
    let walls = maze.walls();
    assert_eq!(walls.len(), 25 - 7);
    // Cell (2, 1) is the wall between the arms of the U: centre ((1−1)·4, (2−1)·4) = (0, 4).
    let inner = walls
        .iter()
        .find(|b| b.center[0] == 0.0 && b.center[1] == 4.0)
        .expect("inner wall");
    assert_eq!(inner.center[2], 1.0);
    assert_eq!(inner.half_extents, [2.0, 2.0, 1.0]);
    let four_rooms = Maze::new(MazeLayout::FourRooms);
    assert!(four_rooms
        .walls()
        .iter()
        .all(|b| b.half_extents == [1.0, 1.0, 0.5] && b.center[2] == 0.5));
    for wall in four_rooms.walls() {
        let cell = four_rooms
            .cell_of([wall.center[0], wall.center[1]])
            .expect("wall inside the grid");
        assert!(four_rooms.is_wall(cell));
    }
}

#[test]
fn cell_lookup_follows_the_codes_ceil_rule() {
    let maze = Maze::new(MazeLayout::U);
    assert_eq!(maze.cell_of([0.0, 0.0]), Some(Cell::new(1, 1)));
    // ceil(2/4 − 0.5) = 0: the boundary belongs to the lower cell.
    assert_eq!(maze.cell_of([2.0, 0.0]), Some(Cell::new(1, 1)));
    assert_eq!(maze.cell_of([2.01, 0.0]), Some(Cell::new(1, 2)));
    assert_eq!(maze.cell_of([-2.01, 0.0]), Some(Cell::new(1, 0)));
    assert_eq!(maze.cell_of([0.0, 8.0]), Some(Cell::new(3, 1)));
    assert_eq!(maze.cell_of([8.0, 4.0]), Some(Cell::new(2, 3)));
    assert_eq!(maze.cell_of([-10.0, 0.0]), None);
    assert_eq!(maze.cell_of([0.0, 14.1]), None);
    assert_eq!(maze.cell_of([f32::NAN, 0.0]), None);
    assert!(maze.is_free_xy([8.0, 4.0]));
    assert!(!maze.is_free_xy([0.0, 4.0]));
}

#[test]
fn bfs_path_distances_on_u_match_hand_computed_values() {
    let maze = Maze::new(MazeLayout::U);
    // Along the U from S = (1, 1): (1,2) 1, (1,3) 2, (2,3) 3, (3,3) 4, (3,2) 5, (3,1) 6.
    let expected = [
        ((1, 1), 0),
        ((1, 2), 1),
        ((1, 3), 2),
        ((2, 3), 3),
        ((3, 3), 4),
        ((3, 2), 5),
        ((3, 1), 6),
    ];
    for ((i, j), d) in expected {
        assert_eq!(
            maze.start_distance(Cell::new(i, j)),
            Some(d),
            "cell ({i}, {j})"
        );
        assert_eq!(
            maze.path_distance(Cell::new(1, 1), Cell::new(i, j)),
            Some(d)
        );
    }
    assert_eq!(maze.max_start_distance(), 6);
    assert_eq!(
        maze.path_distance(Cell::new(3, 1), Cell::new(1, 3)),
        Some(4)
    );
    assert_eq!(
        maze.path_distance(Cell::new(3, 2), Cell::new(3, 2)),
        Some(0)
    );
    assert_eq!(
        maze.path_distance(Cell::new(1, 1), Cell::new(2, 1)),
        None,
        "wall"
    );
    assert_eq!(
        maze.path_distance(Cell::new(1, 1), Cell::new(9, 9)),
        None,
        "outside"
    );
}

#[test]
fn path_distances_in_metres_on_u_follow_the_maze_not_the_straight_line() {
    let maze = Maze::new(MazeLayout::U);
    let goal = maze.test_goal();
    assert_eq!(goal, [0.0, 8.0]);
    // Start to test goal: 6 cells of 4 m, where the straight line is 8 m.
    assert_eq!(maze.path_distance_m([0.0, 0.0], goal), Some(24.0));
    assert_eq!(
        maze.path_distance_m([8.9, 0.3], goal),
        Some(16.0),
        "end of the first corridor"
    );
    assert_eq!(
        maze.path_distance_m([8.0, 4.0], goal),
        Some(12.0),
        "the right column"
    );
    assert_eq!(maze.path_distance_m([4.5, 7.0], goal), Some(4.0));
    assert_eq!(
        maze.path_distance_m([0.5, 9.9], goal),
        Some(0.0),
        "the goal's cell"
    );
    assert_eq!(maze.path_distance_m([0.0, 4.0], goal), None, "a wall cell");
    assert_eq!(
        maze.path_distance_m([100.0, 0.0], goal),
        None,
        "outside the grid"
    );
    assert_eq!(maze.path_distance_m([f32::NAN, 0.0], goal), None);
}

#[test]
fn bfs_path_distance_across_four_rooms_goes_through_the_doors() {
    let maze = Maze::new(MazeLayout::FourRooms);
    // Start (2, 2) → goal (9, 9): Manhattan distance 14, and a door-respecting path of that
    // length exists (down column 2 through door (5, 2), then along row 8 through door (8, 5)).
    assert_eq!(maze.start_distance(Cell::new(9, 9)), Some(14));
    assert_eq!(maze.start_distance(Cell::new(5, 2)), Some(3));
}

#[test]
fn far_goal_rule_on_u_selects_the_bottom_row_like_the_codes_y_at_least_8() {
    let maze = Maze::new(MazeLayout::U);
    // Far = path distance ≥ (2/3)·6 = 4: cells (3,1), (3,2), (3,3), i.e. y in (6, 10].
    for goal in [[0.0, 8.0], [4.0, 8.0], [8.0, 8.0], [-1.9, 9.9], [9.0, 6.5]] {
        assert!(maze.is_far_goal(goal), "{goal:?}");
    }
    for goal in [
        [0.0, 0.0],
        [8.0, 0.0],
        [8.0, 4.0],
        [8.0, 6.0],
        [0.0, 4.0],
        [f32::NAN, 8.0],
    ] {
        assert!(!maze.is_far_goal(goal), "{goal:?}");
    }
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    for _ in 0..2000 {
        let goal = maze.sample_goal(&mut rng);
        assert_eq!(maze.is_far_goal(goal), goal[1] > 6.0, "{goal:?}");
    }
}

#[test]
fn far_goal_rule_on_the_other_mazes_picks_cells_near_the_test_goal() {
    for layout in [MazeLayout::S, MazeLayout::W, MazeLayout::FourRooms] {
        let maze = Maze::new(layout);
        assert!(maze.is_far_goal(maze.test_goal()), "{layout:?}");
        assert!(!maze.is_far_goal([0.0, 0.0]), "{layout:?}");
    }
}

#[test]
fn custom_mazes_are_checked() {
    let vertical = Maze::from_rows(&["###", "#S#", "#G#", "###"], 1.0, 10).expect("valid");
    assert_eq!(vertical.test_goal(), [0.0, 1.0]);
    let ok = Maze::from_rows(&["####", "#SG#", "####"], 1.0, 10).expect("valid");
    assert_eq!(ok.layout(), None);
    assert_eq!(ok.test_goal(), [1.0, 0.0]);
    let cases: [&[&str]; 4] = [
        &["####", "#S.#", "####"],
        &["####", "#SG.", "####"],
        &["#####", "#S#G#", "#####"],
        &["####", "#SG#", "###"],
    ];
    for rows in cases {
        let err = Maze::from_rows(rows, 1.0, 10).expect_err("invalid maze accepted");
        assert!(matches!(err, EnvError::InvalidParam { .. }), "{err}");
    }
    assert!(Maze::from_rows(&["####", "#SG#", "####"], 0.0, 10).is_err());
    assert!(Maze::from_rows(&["####", "#SG#", "####"], 1.0, 0).is_err());
}

proptest! {
    #[test]
    fn training_goals_lie_only_on_free_cells_of_the_goal_box(seed in any::<u64>(), layout_index in 0usize..4) {
        let maze = Maze::new(MazeLayout::ALL[layout_index]);
        let goal_box = maze.goal_box();
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        for _ in 0..64 {
            let goal = maze.sample_goal(&mut rng);
            prop_assert!(goal_box.contains(goal), "{:?} outside {:?}", goal, goal_box);
            let cell = maze.cell_of(goal);
            prop_assert!(cell.is_some_and(|c| maze.is_free(c)), "{:?} in cell {:?}", goal, cell);
        }
    }
}

#[test]
fn rows_give_back_the_layout_and_rebuild_the_same_maze() {
    assert_eq!(
        Maze::new(MazeLayout::U).rows(),
        ["#####", "#S..#", "###.#", "#G..#", "#####"]
    );
    for layout in MazeLayout::ALL {
        let maze = Maze::new(layout);
        let rows = maze.rows();
        let refs: Vec<&str> = rows.iter().map(String::as_str).collect();
        let again = Maze::from_rows(&refs, maze.cell_size_m(), maze.max_steps()).expect("valid");
        assert_eq!(again.free_map(), maze.free_map(), "{layout:?}");
        assert_eq!(again.robot_cell(), maze.robot_cell(), "{layout:?}");
        assert_eq!(again.goal_cell(), maze.goal_cell(), "{layout:?}");
    }
}
