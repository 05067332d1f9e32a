//! The maze renderer writes a PNG of the expected size.

use envs::maze::{Maze, MazeLayout};
use envs::render::{render_maze_png, IMAGE_SIDE_PX};

const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'];

/// Width and height from a PNG's IHDR chunk (bytes 16..24, big-endian).
fn png_size(bytes: &[u8]) -> (u32, u32) {
    let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    (be(&bytes[16..20]), be(&bytes[20..24]))
}

#[test]
fn rendering_a_maze_with_a_trajectory_writes_a_png() {
    let dir = std::env::temp_dir().join(format!("envs-render-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    for layout in MazeLayout::ALL {
        let maze = Maze::new(layout);
        let trajectory = [[0.0, 0.0], [1.0, 0.5], [f32::NAN, 0.0], [2.0, 1.0]];
        let path = dir.join(format!("{layout:?}.png"));
        render_maze_png(&maze, &trajectory, maze.test_goal(), &path).expect("rendered");
        let bytes = std::fs::read(&path).expect("written");
        assert_eq!(bytes[..8], PNG_SIGNATURE, "{layout:?}");
        assert_eq!(
            png_size(&bytes),
            (IMAGE_SIDE_PX, IMAGE_SIDE_PX),
            "{layout:?}: square mazes give square images"
        );
    }
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

#[test]
fn rendering_into_a_missing_directory_is_an_error() {
    let maze = Maze::new(MazeLayout::U);
    let path = std::env::temp_dir()
        .join("envs-render-no-such-dir")
        .join("x")
        .join("maze.png");
    assert!(render_maze_png(&maze, &[], maze.test_goal(), &path).is_err());
}
