#![no_main]
//! Fuzzes the scene TOML parsers (simulate scenes and yarn-level scenes):
//! any text must give a scene or a SceneError, never a panic, and a parsed
//! scene's counts stay within their documented bounds.
use std::path::Path;

use knitvox::pipeline::sim_scene::Scene;
use knitvox::pipeline::yls_scene::{YlsScene, MAX_SCENE_FRAMES};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = Scene::parse(text, Path::new("fuzz.toml"));
    if let Ok(s) = YlsScene::parse(text, Path::new("fuzz.toml")) {
        assert!((s.num_frames() as f64) <= MAX_SCENE_FRAMES + 1.0);
        let _ = s.pose_params();
    }
});
