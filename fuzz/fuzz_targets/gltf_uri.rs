#![no_main]
//! Fuzzes glTF JSON with external-buffer URIs through the confined loader, in
//! a temporary folder that holds a buffer, a symlink leading out and a FIFO,
//! beside a secret file outside it. Any input must give Ok or an error, never
//! a panic or a hang, and never the secret's bytes.
use std::path::PathBuf;
use std::sync::OnceLock;

use knitvox::io::confined::read_confined;
use knitvox::io::{decode, DirResources, Format, ReadOptions};
use libfuzzer_sys::fuzz_target;

const SECRET: &[u8] = b"SECRET-OUTSIDE-THE-FOLDER-0123456789abcdef-SECRET";

fn folder() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let root = std::env::temp_dir().join(format!("knitvox-fuzz-uri-{}", std::process::id()));
        let dir = root.join("in");
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        std::fs::write(root.join("secret.bin"), SECRET).unwrap();
        let floats: Vec<u8> = (0..12).flat_map(|i| (i as f32 * 0.01).to_le_bytes()).collect();
        std::fs::write(dir.join("a.bin"), &floats).unwrap();
        std::fs::write(dir.join("sub").join("b.bin"), &floats).unwrap();
        let _ = std::os::unix::fs::symlink(root.join("secret.bin"), dir.join("out.bin"));
        let _ = std::os::unix::fs::symlink("/dev/zero", dir.join("zero.bin"));
        let fifo = std::ffi::CString::new(dir.join("fifo.bin").to_str().unwrap()).unwrap();
        unsafe { libc::mkfifo(fifo.as_ptr(), 0o644) };
        dir
    })
}

fuzz_target!(|data: &[u8]| {
    let dir = folder();
    let opts = ReadOptions { max_points: 1 << 20, max_memory: 1 << 24, ..ReadOptions::default() };
    if data.first() == Some(&b'{') {
        // Whole documents: any JSON with any buffers.
        let _ = decode(Format::Gltf, data, &opts, &DirResources(dir.clone()));
        return;
    }
    // A URI (and a declared length) in a document that uses the buffer.
    let (len, uri) = match data.split_first() {
        Some((&l, rest)) => (l as u64, String::from_utf8_lossy(rest).into_owned()),
        None => return,
    };
    if let Ok(bytes) = read_confined(dir, &uri, len, len) {
        assert!(bytes.len() as u64 == len);
        assert!(!bytes.windows(6).any(|w| w == b"SECRET"), "read outside the folder: {uri:?}");
    }
    let doc = format!(
        r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"mode":3}}]}}],
        "buffers":[{{"byteLength":{len},"uri":{}}}],
        "bufferViews":[{{"buffer":0,"byteLength":{len}}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":{},"type":"VEC3"}}]}}"#,
        serde_json::to_string(&uri).unwrap(),
        len / 12
    );
    let _ = decode(Format::Gltf, doc.as_bytes(), &opts, &DirResources(dir.clone()));
});
