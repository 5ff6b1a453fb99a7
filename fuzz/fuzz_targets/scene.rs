//! Scene files: arbitrary bytes loaded as a GLB, a glTF (JSON) and an OBJ, through the file
//! system as `envlight render --scene` reads them. A panic that `Scene::load` would catch
//! still aborts here (libFuzzer's panic hook runs first), so it is found.
#![no_main]

use envlight::render::scene::Scene;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&kind, contents)) = data.split_first() else {
        return;
    };
    let ext = match kind % 3 {
        0 => "glb",
        1 => "gltf",
        _ => "obj",
    };
    let dir = std::env::temp_dir().join(format!("envlight-fuzz-scene-{}", std::process::id()));
    if std::fs::create_dir_all(&dir).is_err() {
        return;
    }
    let path = dir.join(format!("scene.{ext}"));
    if std::fs::write(&path, contents).is_ok() {
        let _ = Scene::load(&path, kind & 0x80 != 0);
    }
});
