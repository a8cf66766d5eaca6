//! Mutation fuzzing of the scene parsers in the test suite (the cargo-fuzz
//! target `fuzz/fuzz_targets/scene_toml.rs` runs the same idea unbounded):
//! every shipped scene with one value replaced by a hostile literal, or with
//! random bytes spliced in, parses to an error or to a scene whose numbers
//! are all finite and within their documented ranges, never a panic, and an
//! error message stays short.
use std::path::{Path, PathBuf};

use knitvox::pipeline::sim_scene::Scene;
use knitvox::pipeline::yls_scene::{YlsScene, MAX_SCENE_FRAMES};
use proptest::prelude::*;

mod common;
use common::mutate::{replace_value, value_lines};

/// The longest error message a scene may produce (bytes).
const MAX_MESSAGE: usize = 4096;

const HOSTILE: &[&str] = &[
    "nan",
    "+nan",
    "-nan",
    "inf",
    "-inf",
    "0",
    "-0.0",
    "-1",
    "1e300",
    "-1e300",
    "1e-300",
    "5e-324",
    "18446744073709551615",
    "-9223372036854775808",
    "9223372036854775807",
    "1.7976931348623157e308",
    "\"1/0\"",
    "\"0/0\"",
    "\"-1/150\"",
    "\"1e-300\"",
    "[]",
    "{}",
    "\"\"",
    "true",
];

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples")
}

fn sim_scenes() -> Vec<(PathBuf, String)> {
    let mut v = Vec::new();
    for name in ["fox-walk.toml", "drape-sphere.toml"] {
        let p = examples().join(name);
        v.push((p.clone(), std::fs::read_to_string(&p).unwrap()));
    }
    v
}

fn yls_scenes() -> Vec<(PathBuf, String)> {
    let mut v: Vec<_> = std::fs::read_dir(examples().join("scenes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .map(|p| {
            let t = std::fs::read_to_string(&p).unwrap();
            (p, t)
        })
        .collect();
    v.sort();
    v
}

fn finite(what: &str, x: f64) -> Result<(), String> {
    if x.is_finite() {
        Ok(())
    } else {
        Err(format!("{what} = {x} accepted"))
    }
}

/// The documented ranges of a parsed simulate scene (schemas/sim-scene.md).
fn check_scene(s: &Scene) -> Result<(), String> {
    let sim = &s.simulation;
    finite("dt", sim.dt.0)?;
    if sim.dt.0 <= 0.0 {
        return Err(format!("dt = {} accepted", sim.dt.0));
    }
    finite("fps", sim.fps)?;
    if sim.fps <= 0.0 {
        return Err(format!("fps = {} accepted", sim.fps));
    }
    finite("damping", sim.damping)?;
    finite("friction", sim.friction)?;
    finite("tolerance", sim.tolerance)?;
    for g in sim.gravity {
        finite("gravity", g)?;
    }
    if let Some(p) = sim.preroll {
        finite("preroll", p)?;
        if p < 0.0 {
            return Err(format!("preroll = {p} accepted"));
        }
    }
    for x in s
        .garment
        .rotate_deg
        .iter()
        .chain(s.garment.translate.iter())
    {
        finite("garment placement", *x)?;
    }
    if let Some(c) = &s.character {
        finite("character scale", c.scale)?;
        if c.scale <= 0.0 {
            return Err(format!("character scale = {} accepted", c.scale));
        }
        finite("character thickness", c.thickness)?;
        finite("character pin_distance", c.pin_distance)?;
        finite("character time_offset", c.time_offset)?;
        finite("character fit_gap", c.fit_gap)?;
        for x in c.translate {
            finite("character translate", x)?;
        }
    }
    Ok(())
}

fn short(what: &str, message: &str) -> Result<(), String> {
    if message.len() > MAX_MESSAGE {
        return Err(format!("{what}: a {}-byte error message", message.len()));
    }
    Ok(())
}

/// Checks one scene text; `Ok(true)` when it was refused.
fn run_sim(text: &str, path: &Path) -> Result<bool, String> {
    match Scene::parse(text, path) {
        Ok(s) => check_scene(&s).map(|()| false),
        Err(e) => short("scene", &e.to_string()).map(|()| true),
    }
}

/// Checks one yarn-level scene text; `Ok(true)` when it was refused.
fn run_yls(text: &str, path: &Path) -> Result<bool, String> {
    match YlsScene::parse(text, path) {
        Ok(s) => {
            if s.num_frames() as f64 > MAX_SCENE_FRAMES + 1.0 {
                return Err(format!("{} frames accepted", s.num_frames()));
            }
            let _ = s.pose_params();
            Ok(false)
        }
        Err(e) => short("yarn-level scene", &e.to_string()).map(|()| true),
    }
}

#[test]
fn every_value_of_every_shipped_scene_replaced_by_a_hostile_literal_is_refused_or_in_range() {
    let mut failures = Vec::new();
    let mut cases = 0;
    let mut refused = 0;
    for (path, text) in sim_scenes() {
        for line in value_lines(&text) {
            for v in HOSTILE {
                cases += 1;
                let t = replace_value(&text, line, v);
                match run_sim(&t, &path) {
                    Ok(r) => refused += r as usize,
                    Err(e) => failures.push(format!("{}: line {line} = {v}: {e}", path.display())),
                }
            }
        }
    }
    for (path, text) in yls_scenes() {
        for line in value_lines(&text) {
            for v in HOSTILE {
                cases += 1;
                let t = replace_value(&text, line, v);
                match run_yls(&t, &path) {
                    Ok(r) => refused += r as usize,
                    Err(e) => failures.push(format!("{}: line {line} = {v}: {e}", path.display())),
                }
            }
        }
    }
    assert!(cases > 1000, "only {cases} cases");
    // Most hostile literals are wrong for most keys: a parser that accepted
    // everything would pass the range checks only by luck.
    assert!(refused * 2 > cases, "only {refused} of {cases} refused");
    assert!(
        failures.is_empty(),
        "{} of {cases} hostile scenes got through:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_spliced_into_a_scene_never_panic(
        which in 0usize..64,
        at in 0usize..4096,
        junk in proptest::collection::vec(any::<u8>(), 0..64),
    ) {
        let sims = sim_scenes();
        let ylss = yls_scenes();
        let (path, text) = if which % 2 == 0 {
            &sims[which / 2 % sims.len()]
        } else {
            &ylss[which / 2 % ylss.len()]
        };
        let mut bytes = text.as_bytes().to_vec();
        let at = at % (bytes.len() + 1);
        bytes.splice(at..at, junk);
        let t = String::from_utf8_lossy(&bytes);
        if which % 2 == 0 {
            let r = run_sim(&t, path);
            prop_assert!(r.is_ok(), "{:?}", r);
        } else {
            let r = run_yls(&t, path);
            prop_assert!(r.is_ok(), "{:?}", r);
        }
    }
}
