//! Material cards: their file format, the transfer onto garments
//! (`embed --card`: fibres along each tet's own course, stiffnesses scaled
//! to keep the card's stiffness per unit width, regions) and `knitvox card`
//! end to end on a small swatch.
mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use knitvox::embed::EmbedParams;
use knitvox::geom::card::{
    CardFit, CardMaterial, CardProvenance, CardYarn, MaterialCard, CARD_FORMAT, CARD_VERSION,
};
use knitvox::geom::{Asset, Yarns};
use knitvox::io::{self, ReadOptions, WriteOptions};
use knitvox::pipeline::asset::build_asset;
use knitvox::pipeline::card::swatch_geometry;
use knitvox::pipeline::card_transfer::{
    apply_cards, decode_card, encode_card, CardRegion, CardSpec,
};

fn swatch() -> Yarns {
    common::flat_swatch("stockinette", 6, 6)
}

fn embedded(dir: &Path, name: &str, y: &Yarns, voxel: Option<f64>) -> (PathBuf, Asset) {
    let path = dir.join(format!("{name}.ply"));
    io::write_path(&path, y, None, &WriteOptions::default()).unwrap();
    let params = EmbedParams {
        voxel_size: voxel,
        ..EmbedParams::default()
    };
    let (asset, _) = build_asset(&path, &ReadOptions::default(), &params, "test").unwrap();
    (path, asset)
}

fn card_of(asset: &Asset, gamma_s: f64) -> MaterialCard {
    MaterialCard {
        format: CARD_FORMAT.into(),
        version: CARD_VERSION,
        name: format!("card {gamma_s}"),
        material: CardMaterial {
            gamma_s_pa: gamma_s,
            gamma_v_pa: 3.0 * gamma_s,
            course_pa: 0.03,
            wale_pa: 1.7,
            course_beta: 1.6e5,
            wale_beta: 1.5e4,
        },
        stitch: swatch_geometry(asset).unwrap(),
        yarn: CardYarn {
            young_modulus_pa: 5e5,
            shear_modulus_pa: 2e5,
            bend_scale: 0.3,
            contact_stiffness_j_m2: 60.0,
        },
        friction: 0.25,
        poses: Vec::new(),
        fit: CardFit {
            rms_yarn_diameters: 0.4,
            placeholder_rms_yarn_diameters: 1.3,
            floor_rms_yarn_diameters: 0.15,
            force_misfit: 0.1,
            loss_m3: 4e-6,
            seconds: 70.0,
        },
        provenance: CardProvenance {
            swatch: "stockinette".into(),
            swatch_sha256: "0".repeat(64),
            courses: 6,
            wales: 6,
            knitvox_version: "test".into(),
            command: "test".into(),
        },
    }
}

fn rest(path: &str) -> CardSpec {
    CardSpec {
        path: path.into(),
        region: CardRegion::Rest,
    }
}

#[test]
fn a_card_from_a_small_swatch_lands_unscaled_on_a_large_one_with_fibres_along_the_courses() {
    let dir = tempfile::tempdir().unwrap();
    let (_, small) = embedded(dir.path(), "small", &swatch(), None);
    let card = card_of(&small, 60.0);
    // The same stitch over 16 x 16 stitches, meshed at the card's voxel.
    let big = common::flat_swatch("stockinette", 16, 16);
    let (_, mut a) = embedded(dir.path(), "big", &big, Some(small.grid.h));
    let t = apply_cards(&mut a, &[(rest("c.toml"), card.clone())]).unwrap();
    assert_eq!(t.cards.len(), 1);
    assert_eq!(t.uncovered_tets, 0);
    let s = t.cards[0].scale;
    // The large swatch's fabric measured on its voxels (a rim a voxel wide
    // is a few percent of it) against the card's rectangle.
    assert!((s.stitch_scale - 1.0).abs() < 0.1, "{s:?}");
    assert!((s.factor - 1.0).abs() < 0.15, "{s:?}");
    assert!(t.warnings.is_empty(), "{:?}", t.warnings);
    let f = s.factor;
    let near = |v: &[f64], want: f64| v.iter().all(|&g| (g / want - 1.0).abs() < 1e-9);
    assert!(near(&a.gamma_s, 60.0 * f));
    assert!(near(&a.gamma_v, 180.0 * f));
    let fib = a.fibres.as_ref().expect("fibres");
    assert!(near(&fib.gamma_course, 0.03 * f));
    // Stiffenings are ratios: never scaled.
    assert!(fib.beta_wale.iter().all(|&b| b == 1.5e4));
    // The generator lays its courses along x: the tets' course directions
    // follow (signless).
    let along_x = fib.course.iter().map(|c| c[0].abs()).sum::<f64>() / fib.course.len() as f64;
    assert!(along_x > 0.8, "mean |course . x| = {along_x}");
}

#[test]
fn a_card_keeps_its_stiffness_per_width_on_a_finer_mesh_and_its_pascals_on_a_larger_stitch() {
    let dir = tempfile::tempdir().unwrap();
    let (_, small) = embedded(dir.path(), "small", &swatch(), None);
    let card = card_of(&small, 60.0);
    let h = small.grid.h;
    let y = common::flat_swatch("stockinette", 16, 16);
    let (_, mut coarse) = embedded(dir.path(), "coarse", &y, Some(h));
    let base = apply_cards(&mut coarse, &[(rest("c.toml"), card.clone())])
        .unwrap()
        .cards[0]
        .scale;

    // The same garment meshed at half the voxel: a thinner mesh per
    // fabric area, so stiffer tets, the product kept; the fabric area and
    // the stitch stay.
    let (_, mut fine) = embedded(dir.path(), "fine", &y, Some(0.5 * h));
    let s = apply_cards(&mut fine, &[(rest("c.toml"), card.clone())])
        .unwrap()
        .cards[0]
        .scale;
    assert!(
        (s.stitch_scale / base.stitch_scale - 1.0).abs() < 0.1,
        "{s:?} vs {base:?}"
    );
    assert!(
        s.mesh_thickness_m < 0.8 * base.mesh_thickness_m,
        "{s:?} vs {base:?}"
    );
    let per_width = |x: &knitvox::geom::card::CardScale| x.factor * x.mesh_thickness_m;
    assert!(
        (per_width(&s) / per_width(&base) - 1.0).abs() < 0.1,
        "{s:?} vs {base:?}"
    );

    // The garment knitted twice as large in every length (yarn radius too),
    // meshed at twice the voxel: similar, so the same stiffness in Pa.
    let mut large = y.clone();
    large.map_points(|p| [2.0 * p[0], 2.0 * p[1], 2.0 * p[2]]);
    large.radius.iter_mut().for_each(|r| *r *= 2.0);
    let (_, mut la) = embedded(dir.path(), "large", &large, Some(2.0 * h));
    let t = apply_cards(&mut la, &[(rest("c.toml"), card)]).unwrap();
    let s = t.cards[0].scale;
    assert!(
        (s.stitch_scale / base.stitch_scale - 2.0).abs() < 0.05,
        "{s:?} vs {base:?}"
    );
    assert!(
        (s.factor / base.factor - 1.0).abs() < 0.02,
        "{s:?} vs {base:?}"
    );
    assert!(t.warnings.is_empty(), "{:?}", t.warnings);
}

#[test]
fn a_region_card_takes_the_tets_of_its_box_and_the_rest_card_the_others() {
    let dir = tempfile::tempdir().unwrap();
    let (_, asset) = embedded(dir.path(), "sw", &swatch(), None);
    let b = knitvox::geom::bounds_of(&asset.rest_yarns.points).unwrap();
    let mid = 0.5 * (b.min[0] + b.max[0]);
    let left = CardSpec {
        path: "left.toml".into(),
        region: CardRegion::parse(&format!("box=-1,-1,-1,{mid},1,1")).unwrap(),
    };
    // The region card first on the command line: it still wins over the rest.
    let mut a = asset.clone();
    let t = apply_cards(
        &mut a,
        &[
            (left, card_of(&asset, 500.0)),
            (rest("rest.toml"), card_of(&asset, 60.0)),
        ],
    )
    .unwrap();
    assert_eq!(t.uncovered_tets, 0);
    let (l, r) = (t.cards[0].tets, t.cards[1].tets);
    assert_eq!(l + r, a.mesh.num_tets());
    assert!(
        l > a.mesh.num_tets() / 3 && r > a.mesh.num_tets() / 3,
        "{l} / {r}"
    );
    let centroid_x = |e: usize| {
        a.mesh.tets[e]
            .iter()
            .map(|&n| a.mesh.nodes[n as usize][0])
            .sum::<f64>()
            / 4.0
    };
    let span = b.max[0] - b.min[0];
    for e in 0..a.mesh.num_tets() {
        let x = centroid_x(e);
        if x < mid - 0.1 * span {
            assert!(a.gamma_s[e] > 300.0, "tet {e} at x {x}: {}", a.gamma_s[e]);
        } else if x > mid + 0.1 * span {
            assert!(a.gamma_s[e] < 200.0, "tet {e} at x {x}: {}", a.gamma_s[e]);
        }
    }
}

#[test]
fn card_regions_parse_curves_and_boxes_and_refuse_the_rest() {
    assert_eq!(
        CardRegion::parse("curves=0-3,7").unwrap(),
        CardRegion::Curves(vec![[0, 3], [7, 7]])
    );
    assert_eq!(
        CardRegion::parse("box=1,2,3,0,0,0").unwrap(),
        CardRegion::Box {
            min: [0.0, 0.0, 0.0],
            max: [1.0, 2.0, 3.0]
        }
    );
    for bad in [
        "curves=3-1",
        "curves=a",
        "box=1,2",
        "box=1,2,3,4,5,nan",
        "label=3",
        "nothing",
    ] {
        assert!(CardRegion::parse(bad).is_err(), "{bad}");
    }
}

#[test]
fn a_card_file_round_trips_exactly_and_refuses_what_is_not_a_card() {
    let dir = tempfile::tempdir().unwrap();
    let (_, asset) = embedded(dir.path(), "sw", &swatch(), None);
    let card = card_of(&asset, 67.87502942558422);
    let text = encode_card(&card).unwrap();
    assert_eq!(decode_card(&text).unwrap(), card);
    let not_a_card = "[shot]\nduration = 1\n";
    assert!(decode_card(not_a_card)
        .unwrap_err()
        .contains("not a material card"));
    let later = text.replace("version = 1", "version = 7");
    assert!(decode_card(&later).unwrap_err().contains("version 7"));
    let unknown = text.replace("[material]", "[material]\nshine = 1.0");
    assert!(decode_card(&unknown).unwrap_err().contains("shine"));
    let negative = text.replace("gamma_s_pa = 67.87502942558422", "gamma_s_pa = -1.0");
    assert!(decode_card(&negative)
        .unwrap_err()
        .contains("material.gamma_s_pa"));
}

/// `knitvox embed` with `args`, the exit code and stderr.
fn embed_cli(args: &[&str]) -> (i32, String) {
    let o = Command::new(common::knitvox_bin())
        .arg("embed")
        .args(args)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn embed_refuses_a_bad_card_naming_the_file_and_the_place() {
    let dir = tempfile::tempdir().unwrap();
    let (yarns, asset) = embedded(dir.path(), "sw", &swatch(), None);
    let good = dir.path().join("good.toml");
    std::fs::write(&good, encode_card(&card_of(&asset, 60.0)).unwrap()).unwrap();
    let y = yarns.to_str().unwrap();
    let out = dir.path().join("out.vtkhdf");
    let o = out.to_str().unwrap();
    let cases: [(&str, &str, &str); 3] = [
        (
            "syntax.toml",
            "format = \"knitvox-material-card\"\nversion = = 1\n",
            "line 2",
        ),
        (
            "wrong.toml",
            "format = \"knitvox-shot\"\n",
            "not a material card",
        ),
        ("later.toml", "", "version 9"),
    ];
    for (name, text, want) in cases {
        let p = dir.path().join(name);
        let text = if name == "later.toml" {
            std::fs::read_to_string(&good)
                .unwrap()
                .replace("version = 1", "version = 9")
        } else {
            text.to_string()
        };
        std::fs::write(&p, text).unwrap();
        let (code, err) = embed_cli(&[y, "--card", p.to_str().unwrap(), "-o", o]);
        assert_eq!(code, 65, "{name}: {err}");
        assert!(err.contains(name) && err.contains(want), "{name}: {err}");
        assert!(!out.exists(), "{name}: an asset was written");
    }
    // A missing card: exit 66, before any embedding.
    let (code, err) = embed_cli(&[y, "--card", "missing.toml", "-o", o]);
    assert_eq!(code, 66, "{err}");
    // A malformed region is a usage error.
    let g = format!("{}@box=1,2", good.display());
    let (code, err) = embed_cli(&[y, "--card", &g, "-o", o]);
    assert_eq!(code, 2, "{err}");
    // A device is not read.
    let (code, err) = embed_cli(&[y, "--card", "/dev/zero", "-o", o]);
    assert_eq!(code, 65, "{err}");
    // The good card lands and is recorded in the asset.
    let (code, err) = embed_cli(&[y, "--card", good.to_str().unwrap(), "-o", o]);
    assert_eq!(code, 0, "{err}");
    let a = io::vtkhdf::read_asset(&out).unwrap();
    let rec = &a.parameters["cards"][0];
    assert!(rec["name"] == "card 60", "{rec}");
    let g = rec["material"]["gamma_s_pa"].as_f64().unwrap();
    let f = rec["scale"]["factor"].as_f64().unwrap();
    assert!((g / (60.0 * f) - 1.0).abs() < 1e-12, "{rec}");
    assert!(a.gamma_s.iter().all(|&x| x == g));
    assert!(a
        .provenance
        .inputs
        .iter()
        .any(|i| i.path.ends_with("good.toml")));
}

/// `knitvox card` end to end on a 3 x 3 swatch, one load step per
/// amplitude: the card beats the placeholder on its own training poses,
/// and `embed --card` on the card's swatch gives the fitted swatch's
/// material back, scaled by the transfer's factor.
#[test]
fn the_card_command_fits_a_card_that_beats_the_placeholder_and_transfers_back() {
    let dir = tempfile::tempdir().unwrap();
    let card = dir.path().join("st.toml");
    let o = Command::new(common::knitvox_bin())
        .args([
            "card",
            "stockinette",
            "--courses",
            "3",
            "--wales",
            "3",
            "--steps",
            "1",
            "-o",
        ])
        .arg(&card)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    // A line per step on a non-terminal.
    for step in [
        "embedding the swatch",
        "training pose 3/3",
        "fitting the uniform",
    ] {
        assert!(stderr.contains(step), "{step}: {stderr}");
    }
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("verdict: card"), "{stdout}");
    let (c, _) = knitvox::pipeline::card_transfer::read_card(&card).unwrap();
    assert_eq!(c.poses.len(), 3);
    assert!(
        c.fit.rms_yarn_diameters < c.fit.placeholder_rms_yarn_diameters,
        "{:?}",
        c.fit
    );
    assert!(c.fit.rms_yarn_diameters >= c.fit.floor_rms_yarn_diameters * 0.999);
    let work = dir.path().join("st.work");
    let fitted = io::vtkhdf::read_asset(&work.join("fitted.vtkhdf")).unwrap();
    let out = dir.path().join("back.vtkhdf");
    let (code, err) = embed_cli(&[
        work.join("swatch.h5").to_str().unwrap(),
        "--card",
        card.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let back = io::vtkhdf::read_asset(&out).unwrap();
    assert_eq!(back.mesh.num_tets(), fitted.mesh.num_tets());
    // The card's rectangle against the swatch's voxels, rim and all: a
    // small swatch's factor is above 1.
    let f = back.parameters["cards"][0]["scale"]["factor"]
        .as_f64()
        .unwrap();
    assert!((1.0..2.0).contains(&f), "{f}");
    let rel = |a: f64, b: f64| (a - b).abs() / b.abs();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(rel(mean(&back.gamma_s), f * mean(&fitted.gamma_s)) < 1e-9);
    let (bf, ff) = (back.fibres.unwrap(), fitted.fibres.unwrap());
    assert!(rel(mean(&bf.gamma_wale), f * mean(&ff.gamma_wale)) < 1e-9);
    assert!(rel(mean(&bf.beta_course), mean(&ff.beta_course)) < 1e-9);
}

/// `knitvox run JOB.toml --stage embed`: exit code and stderr.
fn run_embed(job: &Path) -> (i32, String) {
    let o = Command::new(common::knitvox_bin())
        .args(["run", job.to_str().unwrap(), "--stage", "embed"])
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn a_job_manifest_embeds_with_its_cards_reruns_when_a_card_changes_and_keeps_cards_inside() {
    let dir = tempfile::tempdir().unwrap();
    let (_, asset) = embedded(dir.path(), "sw", &swatch(), None);
    std::fs::write(
        dir.path().join("st.toml"),
        encode_card(&card_of(&asset, 60.0)).unwrap(),
    )
    .unwrap();
    let job = dir.path().join("job.toml");
    let manifest =
        |cards: &str| format!("[garment]\nyarns = \"sw.ply\"\n\n[embed]\ncards = [{cards}]\n");
    std::fs::write(&job, manifest("\"st.toml\"")).unwrap();
    let (code, err) = run_embed(&job);
    assert_eq!(code, 0, "{err}");
    let out = dir.path().join("job.out").join("garment.vtkhdf");
    let first = io::vtkhdf::read_asset(&out).unwrap();
    let g0 = first.gamma_s[0];
    assert!(first.gamma_s.iter().all(|&g| g == g0) && g0 < 1e3, "{g0}");
    // A refitted card (another material) re-runs the stage.
    std::fs::write(
        dir.path().join("st.toml"),
        encode_card(&card_of(&asset, 120.0)).unwrap(),
    )
    .unwrap();
    let (code, err) = run_embed(&job);
    assert_eq!(code, 0, "{err}");
    let second = io::vtkhdf::read_asset(&out).unwrap();
    assert!(
        (second.gamma_s[0] / g0 - 2.0).abs() < 1e-9,
        "{} vs {g0}",
        second.gamma_s[0]
    );
    // A card outside the manifest's folder and a bad region are refused
    // naming the key.
    let outside = tempfile::tempdir().unwrap();
    let far = outside.path().join("far.toml");
    std::fs::copy(dir.path().join("st.toml"), &far).unwrap();
    std::fs::write(&job, manifest(&format!("{:?}", far.display().to_string()))).unwrap();
    let (code, err) = run_embed(&job);
    assert_eq!(code, 65, "{err}");
    assert!(err.contains("[embed] cards"), "{err}");
    std::fs::write(&job, manifest("\"st.toml@box=1,2\"")).unwrap();
    let (code, err) = run_embed(&job);
    assert_eq!(code, 65, "{err}");
    assert!(err.contains("embed.cards"), "{err}");
}
