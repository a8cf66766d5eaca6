//! Pattern character after the relaxation into contact:
//! a stockinette swatch curls its edges (the course ends to the back, the
//! top and bottom to the front), a 1x1 rib stays flat and draws in, garter
//! shortens; `knitvox pattern --json` reports the relaxed size, contacts
//! per vertex and the minimum distance ratio.

use knitvox::pipeline::pattern::{generate, PatternJob, PatternReport, PatternSource};
use knitvox::yarn::fabric::RelaxParams;
use knitvox::yarn::pattern::{Character, Layout, PatternParams};

/// A flat `courses` x `wales` swatch of a built-in through the `knitvox
/// pattern` stage, relaxed keeping `RelaxParams::CHARACTER_REST_CURVATURE`
/// of the generated curvature as rest curvature.
fn relaxed(pattern: &str, courses: usize, wales: usize) -> PatternReport {
    let job = PatternJob {
        source: PatternSource::Builtin(pattern.into()),
        layout: Layout {
            courses,
            wales,
            tube_radius: None,
            helix: false,
            separate_courses: false,
        },
        params: PatternParams::default(),
        relax: Some(RelaxParams::with_character()),
        material: knitvox::yarn::fabric::FabricParams::default().material(),
    };
    generate(&job).unwrap().1
}

fn character(r: &PatternReport) -> Character {
    r.character
        .expect("a relaxed flat swatch reports its character")
}

#[test]
fn stockinette_curls_rib_stays_flat_and_draws_in_garter_shortens() {
    let d = 2.0 * PatternParams::default().yarn_radius;
    let stock = relaxed("stockinette", 6, 6);
    let rib = relaxed("rib1x1", 6, 6);
    let garter = relaxed("garter", 6, 6);
    let (s, r, g) = (character(&stock), character(&rib), character(&garter));
    println!("stockinette {s:?}\nrib {r:?}\ngarter {g:?}");
    // Stockinette: the course ends roll to the back by more than two yarn
    // diameters, the top and bottom edges rise to the front.
    assert!(s.side_curl_m < -2.0 * d, "stockinette {s:?}");
    assert!(s.end_curl_m > 0.25 * d, "stockinette {s:?}");
    // Rib: balanced between the faces, its edges stay within a quarter
    // diameter of the plane on average, and it is at least 10% narrower
    // than generated.
    assert!(
        r.side_curl_m.abs() < 0.25 * d && r.end_curl_m.abs() < 0.25 * d,
        "rib {r:?}"
    );
    assert!(r.width_ratio < 0.9, "rib {r:?}");
    // Garter: shorter (relative to the generated swatch) than the rib and
    // the stockinette by at least 3% of the generated height, and flat.
    assert!(
        g.height_ratio < r.height_ratio - 0.03 && g.height_ratio < s.height_ratio - 0.03,
        "garter {g:?}, rib {r:?}, stockinette {s:?}"
    );
    assert!(g.side_curl_m.abs() < 0.5 * d, "garter {g:?}");
    // Held by contact, nothing passed through.
    for rep in [&stock, &rib, &garter] {
        assert!(rep.min_distance_ratio >= 0.75, "{}", rep.min_distance_ratio);
        assert!(rep.contacts_per_vertex.unwrap() > 0.2, "{rep:?}");
        assert!(rep.near_fraction.unwrap() >= 0.15, "{rep:?}");
    }
    // The report carries the relaxed size and the character in JSON.
    let json = serde_json::to_value(&rib).unwrap();
    let c = &json["character"];
    assert_eq!(
        c["relaxed_size"][0].as_f64().unwrap(),
        rib.size[0],
        "{json}"
    );
    for key in ["width_ratio", "height_ratio", "side_curl_m", "end_curl_m"] {
        assert!(c[key].is_f64(), "{key} missing: {json}");
    }
    assert!(json["contacts_per_vertex"].is_f64());
}

#[test]
fn unrelaxed_and_tube_swatches_report_no_character() {
    let job = PatternJob {
        source: PatternSource::Builtin("stockinette".into()),
        layout: Layout {
            courses: 3,
            wales: 3,
            tube_radius: None,
            helix: false,
            separate_courses: false,
        },
        params: PatternParams::default(),
        relax: None,
        material: knitvox::yarn::fabric::FabricParams::default().material(),
    };
    let (_, r) = generate(&job).unwrap();
    assert!(r.character.is_none() && r.contacts_per_vertex.is_none());
}
