//! Graph-service checkpoints: a round trip restores the store, counts, maps and φ and gives
//! the same answers; damaged, incompatible and half-written checkpoints are refused or ignored.

mod common;

use std::fs;
use std::path::{Path, PathBuf};

use common::*;
use graph_service::checkpoint::{CheckpointError, FileError, Manifest, MANIFEST, SUBDIR};
use graph_service::GraphService;
use protocol::graph::{ReachSample, RouteAnswer, RouteQuery};
use protocol::{GraphRequest, GraphResponse};

/// A fresh scratch folder for one test.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("asi-graph-ckpt-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    dir.join("checkpoints").join(SUBDIR)
}

/// Removes the scratch run folder of `dir` (made by [`scratch`]).
fn remove(dir: &Path) {
    let run = dir.parent().and_then(Path::parent).unwrap();
    fs::remove_dir_all(run).unwrap();
}

/// A service with closed and open trajectories, a lost chunk, φ v2 (scale 2) loaded, states
/// that arrived after the φ, reach reports and some answered requests; rebuilt at the end so
/// its graph holds every stored state.
fn busy_service() -> GraphService {
    let config = config();
    let mut s = service(&config);
    let arms = [(1, 0), (-1, 0), (0, 1), (0, -1)];
    for (episode, (dx, dy)) in arms.into_iter().enumerate() {
        let arm: Vec<_> = (0..=4).map(|i| at(i * dx, i * dy)).collect();
        ingest_episode(&mut s, 0, episode as u64, &arm);
    }
    // An open trajectory, then a chunk of another episode of actor 1 after a lost one.
    let mut open = Chunk::new(1, 9);
    open.end = false;
    let (h, p) = open.encode(&[at(3, 3), at(3, 4), at(4, 4)]);
    s.ingest(&h, &p).unwrap();
    let mut late = Chunk::new(1, 10);
    late.chunk_index = 2;
    late.first_env_step = 40;
    let (h, p) = late.encode(&[at(6, 6), at(6, 7)]);
    s.ingest(&h, &p).unwrap();
    let (h, p) = weights(&actor_side_params(&config, 2.0), 2);
    s.load_weights(&h, &p).unwrap();
    ingest_episode(&mut s, 2, 0, &[at(1, 1), at(1, 2), at(2, 2)]);
    let report = GraphRequest::ReportReaching {
        samples: vec![
            ReachSample {
                subgoal: [2.5, 0.5],
                error: 1.5,
            },
            ReachSample {
                subgoal: [-7.0, 0.5],
                error: 0.25,
            },
        ],
    };
    ask(&mut s, &report);
    ask(&mut s, &GraphRequest::FrontierRoute { from: [0.5, 0.5] });
    s.rebuild();
    s
}

/// The bodies of a fixed list of requests (frontier, routes, explore, least visited), at
/// points in φ-space (φ = 2·xy: the arms' cells are (1, 1), (3, 1), … (9, 1) and so on).
fn answers(s: &mut GraphService) -> Vec<Option<GraphResponse>> {
    let requests = [
        GraphRequest::FrontierRoute { from: [1.5, 1.5] },
        GraphRequest::FrontierRoute { from: [5.5, 1.5] },
        GraphRequest::Routes {
            queries: vec![
                RouteQuery {
                    start: [1.5, 1.5],
                    end: [9.5, 1.5],
                    fallback_origin: None,
                },
                RouteQuery {
                    start: [1.5, 1.5],
                    end: [40.0, 40.0],
                    fallback_origin: Some([1.5, 1.5]),
                },
            ],
        },
        GraphRequest::ExploreSubgoal {
            from: [2.0, 2.0],
            episode: 3,
        },
        GraphRequest::ExploreSubgoal {
            from: [2.0, 2.0],
            episode: 1_000,
        },
        GraphRequest::LeastVisited {
            candidates: vec![[1.5, 1.5], [5.5, 5.5], [9.5, 1.5]],
        },
    ];
    requests.iter().map(|r| ask(s, r).1).collect()
}

#[test]
fn a_restored_service_holds_the_same_state_and_gives_the_same_answers() {
    let dir = scratch("round-trip");
    let config = config();
    let mut original = busy_service();
    let ckpt = original.save(&dir).unwrap();
    assert_eq!(ckpt.manifest.sequence, 1);
    assert_eq!(ckpt.manifest.phi_version, 2);
    let (mut restored, from) = GraphService::restore(&ckpt.path, &config, dims()).unwrap();
    assert_eq!(from, ckpt);
    assert_eq!(restored.store(), original.store());
    assert_eq!(restored.counts(), original.counts());
    assert_eq!(restored.hess(), original.hess());
    assert_eq!(restored.phi_version(), original.phi_version());
    let (a, b) = (original.stats(), restored.stats());
    assert_eq!(b, a, "the graph and its version as saved");
    assert_same_graph(&restored, &original);
    assert!(
        a.reach_samples == 2 && a.chunk_gaps == 1 && a.stored_steps > 20,
        "{a:?}"
    );
    let expected = answers(&mut original);
    assert!(
        matches!(expected[0], Some(GraphResponse::FrontierRoute(Ok(_))))
            && matches!(expected[1], Some(GraphResponse::FrontierRoute(Ok(_))))
            && matches!(&expected[2], Some(GraphResponse::Routes(r)) if matches!(r[0], RouteAnswer::Direct(_)))
            && matches!(expected[3], Some(GraphResponse::ExploreSubgoal { .. })),
        "{expected:?}"
    );
    assert_eq!(answers(&mut restored), expected);
    // The same φ: a chunk labelled with another φ version is mapped alike by both.
    let mut chunk = Chunk::new(3, 0);
    chunk.phi_version = 1;
    let (h, p) = chunk.encode(&[at(5, 5), at(5, 6)]);
    original.ingest(&h, &p).unwrap();
    restored.ingest(&h, &p).unwrap();
    assert_eq!(restored.store(), original.store());
    assert_eq!(restored.visits([11.0, 11.0]), Some(1), "φ = 2·xy");
    remove(&dir);
}

#[test]
fn a_service_without_weights_round_trips_and_keeps_no_phi_file() {
    let dir = scratch("no-phi");
    let config = config();
    let mut s = service(&config);
    ingest_episode(&mut s, 0, 0, &[at(0, 0), at(1, 0), at(2, 0)]);
    let ckpt = s.save(&dir).unwrap();
    assert!(ckpt
        .manifest
        .files
        .iter()
        .all(|f| f.name != "phi.safetensors"));
    let (restored, _) = GraphService::restore(&ckpt.path, &config, dims()).unwrap();
    assert_eq!(restored.store(), s.store());
    assert_eq!(restored.phi_version().0, 0);
    // No graph before the first rebuild, and none after the restore.
    assert!(s.graph().is_none() && restored.graph().is_none());
    assert!(ckpt
        .manifest
        .files
        .iter()
        .all(|f| f.name != "graph.safetensors"));
    remove(&dir);
}

/// The graphs of `a` and `b` are the same: nodes, edges, dropped cells and unmapped states.
fn assert_same_graph(a: &GraphService, b: &GraphService) {
    let (a, b) = (a.graph().unwrap(), b.graph().unwrap());
    assert_eq!(a.keys(), b.keys());
    assert_eq!(a.edges(), b.edges());
    assert_eq!(a.adjacency(), b.adjacency());
    assert_eq!(
        (a.n_dropped_cells(), a.n_unmapped_states()),
        (b.n_dropped_cells(), b.n_unmapped_states())
    );
}

/// `busy_service` with an episode in new cells stored after its last rebuild: its graph lags
/// its store, as a running service's does between φ re-maps.
fn lagging_service() -> GraphService {
    let mut s = busy_service();
    let nodes = s.graph().unwrap().n_nodes();
    ingest_episode(&mut s, 3, 0, &[at(10, 10), at(10, 11), at(11, 11)]);
    assert_eq!(s.graph().unwrap().n_nodes(), nodes, "no rebuild on ingest");
    s
}

#[test]
fn a_graph_that_lags_the_store_is_restored_as_it_was_not_rebuilt() {
    let dir = scratch("lagging-graph");
    let config = config();
    let mut original = lagging_service();
    let ckpt = original.save(&dir).unwrap();
    let (mut restored, _) = GraphService::restore(&ckpt.path, &config, dims()).unwrap();
    assert_eq!(restored.stats(), original.stats());
    assert_same_graph(&restored, &original);
    // The new cells are stored and counted but in neither graph: from one of them no route.
    let far = [21.0, 21.0]; // φ = 2·xy of at(10, 10)
    assert_eq!(restored.visits(far), Some(1));
    assert!(restored.graph().unwrap().node_at(far).is_none());
    assert_eq!(answers(&mut restored), answers(&mut original));
    // A rebuild (what a restore did before graphs were saved) takes them in.
    let nodes = original.graph().unwrap().n_nodes();
    restored.rebuild();
    assert_eq!(restored.graph().unwrap().n_nodes(), nodes + 3);
    remove(&dir);
}

#[test]
fn a_checkpoint_from_before_graphs_were_saved_rebuilds_the_graph_from_the_store() {
    let dir = scratch("no-graph-file");
    let original = lagging_service();
    let path = original.save(&dir).unwrap().path;
    // As an older writer wrote it: no graph file, no `graph_saved` in state.json.
    fs::remove_file(path.join("graph.safetensors")).unwrap();
    let file = path.join("state.json");
    // Edited as text: the generator's 128-bit numbers do not survive a serde_json::Value.
    let state = fs::read_to_string(&file).unwrap();
    let line = "\n  \"graph_saved\": true,";
    assert!(state.contains(line), "{state}");
    let older = state.replacen(line, "", 1).into_bytes();
    fs::write(&file, &older).unwrap();
    edit_manifest(&path, |m| {
        m.files.retain(|f| f.name != "graph.safetensors");
        let entry = m.files.iter_mut().find(|f| f.name == "state.json").unwrap();
        *entry = ckpt::FileEntry::of("state.json", &older);
    });
    let (restored, _) = GraphService::restore(&path, &config(), dims()).unwrap();
    let (a, b) = (original.stats(), restored.stats());
    assert_eq!(b.graph_version, a.graph_version + 1, "one rebuild");
    assert_eq!(b.n_nodes, a.n_nodes + 3, "from the whole store");
    remove(&dir);
}

#[test]
fn a_graph_file_no_built_graph_could_have_is_refused_as_corrupt() {
    let (dir, path) = saved("bad-graph");
    let file = path.join("graph.safetensors");
    let bytes = fs::read(&file).unwrap();
    let (st, metadata) = ckpt::parse(&bytes).unwrap();
    let keys: Vec<i32> = ckpt::array(&st, "keys", None).unwrap();
    let mut edges: Vec<u32> = ckpt::array(&st, "edges", None).unwrap();
    assert!(edges.len() >= 3, "busy_service's graph has edges");
    // The first edge turned round (b, a): a writer of this format never writes it.
    edges.swap(0, 1);
    let keys = ckpt::Array::from_iter(vec![keys.len() / 2, 2], keys).unwrap();
    let edges = ckpt::Array::from_iter(vec![edges.len() / 3, 3], edges).unwrap();
    let tensors = vec![("keys".to_owned(), &keys), ("edges".to_owned(), &edges)];
    let bad = ckpt::serialize(tensors, metadata).unwrap();
    fs::write(&file, &bad).unwrap();
    edit_manifest(&path, |m| {
        let entry = m
            .files
            .iter_mut()
            .find(|f| f.name == "graph.safetensors")
            .unwrap();
        *entry = ckpt::FileEntry::of("graph.safetensors", &bad);
    });
    match restore_err(&path) {
        CheckpointError::File(FileError::Corrupt { path, problem }) => {
            assert_eq!(path, file);
            assert!(problem.contains("a < b"), "{problem}");
        }
        other => panic!("expected Corrupt, got {other}"),
    }
    remove(&dir);
}

#[test]
fn a_service_holding_the_initial_phi_0_restores_it_and_ignores_its_rebroadcast() {
    let dir = scratch("phi-0");
    let config = config();
    let mut s = service(&config);
    let (h, p) = weights(&actor_side_params(&config, 2.0), 0);
    s.load_weights(&h, &p).unwrap();
    ingest_episode(&mut s, 0, 0, &[at(0, 0), at(1, 0), at(2, 0)]);
    let ckpt = s.save(&dir).unwrap();
    assert_eq!(ckpt.manifest.phi_version, 0);
    assert!(ckpt
        .manifest
        .files
        .iter()
        .any(|f| f.name == "phi.safetensors"));
    let (mut restored, _) = GraphService::restore(&ckpt.path, &config, dims()).unwrap();
    // The learner broadcasts φ 0 until its first φ round. It is not newer than the φ held, so
    // neither service re-maps its states (φ = 2·xy would move them) or rebuilds its graph.
    let versions = (s.stats().graph_version, restored.stats().graph_version);
    s.load_weights(&h, &p).unwrap();
    restored.load_weights(&h, &p).unwrap();
    assert_eq!(
        (s.stats().graph_version, restored.stats().graph_version),
        versions
    );
    assert_eq!(restored.store(), s.store());
    assert_eq!(restored.counts(), s.counts());
    remove(&dir);
}

/// Saves `busy_service` into a fresh folder; returns the folder and checkpoint path.
fn saved(name: &str) -> (PathBuf, PathBuf) {
    let dir = scratch(name);
    let ckpt = busy_service().save(&dir).unwrap();
    (dir, ckpt.path)
}

fn restore_err(path: &Path) -> CheckpointError {
    GraphService::restore(path, &config(), dims()).unwrap_err()
}

/// Restoring the checkpoint at `path` fails: `file` is corrupt by its checksum.
fn assert_refused_by_checksum(path: &Path, file: &Path) {
    match restore_err(path) {
        CheckpointError::File(FileError::Corrupt { path, problem }) => {
            assert_eq!(path, file);
            assert!(problem.contains("checksum"), "{problem}");
        }
        other => panic!("expected Corrupt, got {other}"),
    }
}

#[test]
fn a_flipped_byte_is_refused_as_corrupt_naming_the_file() {
    let (dir, path) = saved("flipped");
    let file = path.join("store.safetensors");
    let mut bytes = fs::read(&file).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x01;
    fs::write(&file, bytes).unwrap();
    assert_refused_by_checksum(&path, &file);
    remove(&dir);
}

#[test]
fn a_truncated_file_is_refused_as_corrupt() {
    let (dir, path) = saved("truncated");
    let file = path.join("maps.safetensors");
    let bytes = fs::read(&file).unwrap();
    fs::write(&file, &bytes[..bytes.len() - 7]).unwrap();
    match restore_err(&path) {
        CheckpointError::File(FileError::Corrupt { path, problem }) => {
            assert_eq!(path, file);
            assert!(problem.contains("truncated"), "{problem}");
        }
        other => panic!("expected Corrupt, got {other}"),
    }
    // A truncated manifest is corrupt too.
    let manifest = path.join(MANIFEST);
    let text = fs::read(&manifest).unwrap();
    fs::write(&manifest, &text[..text.len() / 2]).unwrap();
    assert!(matches!(
        restore_err(&path),
        CheckpointError::File(FileError::Corrupt { .. })
    ));
    remove(&dir);
}

/// Rewrites the manifest of `path` through `edit`.
fn edit_manifest(path: &Path, edit: impl FnOnce(&mut Manifest)) {
    let file = path.join(MANIFEST);
    let mut manifest: Manifest = serde_json::from_slice(&fs::read(&file).unwrap()).unwrap();
    edit(&mut manifest);
    fs::write(&file, serde_json::to_vec_pretty(&manifest).unwrap()).unwrap();
}

#[test]
fn another_format_version_or_config_shape_is_refused_as_incompatible() {
    let (dir, path) = saved("incompatible");
    edit_manifest(&path, |m| m.format_version += 1);
    match restore_err(&path) {
        CheckpointError::File(FileError::Incompatible {
            what,
            expected,
            found,
            ..
        }) => {
            assert_eq!(what, "format version");
            let current = graph_service::checkpoint::FORMAT_VERSION;
            assert_eq!(found, (current + 1).to_string());
            assert_eq!(expected, format!("1 to {current}"));
        }
        other => panic!("expected Incompatible, got {other}"),
    }
    edit_manifest(&path, |m| m.format_version -= 1);
    assert!(GraphService::restore(&path, &config(), dims()).is_ok());
    let mut other = config();
    other.graph.cell_size = 2.0;
    let err = GraphService::restore(&path, &other, dims()).unwrap_err();
    assert!(
        matches!(&err, CheckpointError::File(FileError::Incompatible { what, .. }) if what == "graph.cell_size"),
        "{err}"
    );
    assert!(err.to_string().contains("this run needs 2"), "{err}");
    remove(&dir);
}

#[test]
fn an_interrupted_write_leaves_the_previous_checkpoint_in_use() {
    let dir = scratch("interrupted");
    let config = config();
    let mut s = busy_service();
    let first = s.save(&dir).unwrap();
    // A write of checkpoint 2 that died half-way: its temporary folder, partly filled.
    let tmp = dir.join(".tmp-ckpt-000002");
    fs::create_dir_all(&tmp).unwrap();
    fs::write(tmp.join("store.safetensors"), b"half").unwrap();
    let resumed = GraphService::restore_newest_valid(&dir, &config, dims()).unwrap();
    let (restored, from) = resumed.restored.unwrap();
    assert_eq!(from.path, first.path);
    assert!(resumed.refused.is_empty());
    assert_eq!(restored.store(), s.store());
    // The next write replaces the leftover and keeps the newest two.
    ingest_episode(&mut s, 5, 0, &[at(9, 9), at(9, 8)]);
    let second = s.save(&dir).unwrap();
    assert_eq!(second.manifest.sequence, 2);
    assert!(!tmp.exists());
    s.save(&dir).unwrap();
    assert!(!first.path.exists(), "only the newest two are kept");
    assert_eq!(fs::read_dir(&dir).unwrap().count(), 2);
    remove(&dir);
}

#[test]
fn a_damaged_newest_checkpoint_falls_back_to_the_previous_one() {
    let dir = scratch("fallback");
    let config = config();
    let mut s = busy_service();
    let first = s.save(&dir).unwrap();
    ingest_episode(&mut s, 5, 0, &[at(9, 9), at(9, 8)]);
    let second = s.save(&dir).unwrap();
    fs::remove_file(second.path.join("state.json")).unwrap();
    let resumed = GraphService::restore_newest_valid(&dir, &config, dims()).unwrap();
    assert_eq!(resumed.restored.unwrap().1.path, first.path);
    assert_eq!(resumed.refused.len(), 1);
    assert_eq!(resumed.refused[0].0, second.path);
    assert!(matches!(
        resumed.refused[0].1,
        CheckpointError::File(FileError::Io { .. })
    ));
    let empty = GraphService::restore_newest_valid(&dir.join("none"), &config, dims()).unwrap();
    assert!(empty.restored.is_none() && empty.refused.is_empty());
    remove(&dir);
}

#[test]
fn a_checkpoint_from_before_the_episode_counter_restores_it_from_the_store() {
    let (dir, path) = saved("no-episode-counter");
    let original = busy_service();
    // Closed: the four arms, the late trajectory (its chunk ends the episode) and the episode
    // of actor 2; the open one is not.
    assert_eq!(original.hess().episodes_stored(), 6);
    // Rewrite maps.safetensors as an older writer did: without `episodes_stored`.
    let file = path.join("maps.safetensors");
    let bytes = fs::read(&file).unwrap();
    let (st, mut metadata) = ckpt::parse(&bytes).unwrap();
    assert!(metadata.remove("episodes_stored").is_some());
    let older = ckpt::serialize(st.tensors(), metadata).unwrap();
    fs::write(&file, &older).unwrap();
    edit_manifest(&path, |m| {
        let entry = m
            .files
            .iter_mut()
            .find(|f| f.name == "maps.safetensors")
            .unwrap();
        *entry = ckpt::FileEntry::of("maps.safetensors", &older);
    });
    let (restored, _) = GraphService::restore(&path, &config(), dims()).unwrap();
    // The store's closed trajectories: the same number, since nothing was evicted.
    assert_eq!(restored.hess().episodes_stored(), 6);
    assert_eq!(restored.hess(), original.hess());
    remove(&dir);
}

#[test]
fn a_two_bit_error_that_the_format_1_checksum_misses_is_refused_as_corrupt() {
    let (dir, path) = saved("two-bits");
    let file = path.join("store.safetensors");
    let before = fs::read(&file).unwrap();
    // The top bit of the last two whole 8-byte words: the word-wise FNV-1a of format 1 cannot
    // see it (the two flips reach only the top bit of its state and cancel).
    let mut after = before.clone();
    let end = before.len() / 8 * 8;
    after[end - 9] ^= 0x80;
    after[end - 1] ^= 0x80;
    assert_eq!(
        ckpt::Checksum::Fnv1aWords.of(&before),
        ckpt::Checksum::Fnv1aWords.of(&after)
    );
    fs::write(&file, &after).unwrap();
    assert_refused_by_checksum(&path, &file);
    remove(&dir);
}

#[test]
fn a_format_1_checkpoint_still_restores_with_its_own_checksums() {
    let (dir, path) = saved("format-1");
    let file = path.join(MANIFEST);
    let current: Manifest = serde_json::from_slice(&fs::read(&file).unwrap()).unwrap();
    assert_eq!(current.format_version, 2);
    let original = busy_service();
    // As a format-1 build wrote it: the same files, word-wise FNV-1a sums.
    edit_manifest(&path, |m| {
        m.format_version = 1;
        for entry in &mut m.files {
            let bytes = fs::read(path.join(&entry.name)).unwrap();
            entry.checksum = format!("{:016x}", ckpt::Checksum::Fnv1aWords.of(&bytes));
        }
    });
    let (restored, _) = GraphService::restore(&path, &config(), dims()).unwrap();
    assert_eq!(restored.store(), original.store());
    assert_eq!(restored.counts(), original.counts());
    assert_eq!(restored.hess(), original.hess());
    // Format 1 with the CRC sums of format 2 is refused: each format is read with its own.
    fs::write(&file, serde_json::to_vec_pretty(&current).unwrap()).unwrap();
    edit_manifest(&path, |m| m.format_version = 1);
    assert!(matches!(
        restore_err(&path),
        CheckpointError::File(FileError::Corrupt { .. })
    ));
    remove(&dir);
}
