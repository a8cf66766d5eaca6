//! Every published yarn model in $KNITVOX_EXTERNAL_DATA/yarns reads through the path API.
mod common;

use knitvox::io::{read_path, Format, ReadOptions};

#[test]
fn every_external_yarn_file_reads() {
    let Some(dir) = common::external_data("yarns") else {
        return;
    };
    let mut read = 0;
    let mut entries: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for path in entries {
        if Format::from_path(&path).is_none() {
            continue; // certificates and other side files
        }
        let d = read_path(&path, &ReadOptions::default()).unwrap_or_else(|e| panic!("{e}"));
        assert!(
            d.yarns.num_curves() > 0 && d.yarns.num_points() > 1,
            "{}",
            path.display()
        );
        d.yarns.validate().unwrap();
        read += 1;
    }
    // 8 BCC, 6 PYP and 1 OBJ model.
    assert_eq!(read, 15, "expected 15 yarn models");
}
