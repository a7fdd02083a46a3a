//! Ctrl-C while a command writes its outputs (issue 19, item 9): a real SIGINT, in a process
//! of its own (this test binary), since it marks the whole process interrupted.
#![cfg(unix)]

use std::fs;
use sylva_core::{interrupt, OutputSet};

#[test]
fn sigint_while_writing_replaces_nothing_and_leaves_no_temporary() {
    interrupt::install();
    let dir = tempfile::tempdir().unwrap();
    let (png, exr) = (dir.path().join("demo.png"), dir.path().join("demo.exr"));
    fs::write(&png, b"old png").unwrap();
    fs::write(&exr, b"old exr").unwrap();
    let mut set = OutputSet::new::<&std::path::Path>(&[]);
    set.write_bytes(&png, b"new png").unwrap();
    // Ctrl-C arrives in the middle of the (large) EXR: the handler must not end the process
    // while temporaries exist, and the writer must stop.
    let e = set
        .write(&exr, |w| {
            for i in 0..1000 {
                if i == 10 {
                    // SAFETY: raising a signal this process handles.
                    unsafe { libc::raise(libc::SIGINT) };
                }
                w.write_all(&[0u8; 1 << 16])?;
            }
            Ok(())
        })
        .unwrap_err();
    assert!(interrupt::interrupted());
    assert!(e.to_string().contains("interrupted"), "{e}");
    assert!(set.commit().is_err(), "an interrupted set must not commit");
    assert_eq!(fs::read(&png).unwrap(), b"old png");
    assert_eq!(fs::read(&exr).unwrap(), b"old exr");
    let names: Vec<_> = fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 2, "temporaries left behind: {names:?}");
}

/// Issue 19, item 4: a file this process read is never replaced by one of its outputs.
#[test]
fn inputs_read_are_never_overwritten() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("ok.obj");
    fs::write(&model, b"v 0 0 0\n").unwrap();
    sylva_core::read_file(&model, 1 << 20, "model files").unwrap();
    let e = sylva_core::atomic_write(&dir.path().join("./ok.obj"), b"grid").unwrap_err();
    assert!(e.to_string().contains("is an input of this command"), "{e}");
    let mut set = OutputSet::new::<&std::path::Path>(&[]);
    assert!(set.plan(&[&model]).is_err());
    assert_eq!(fs::read(&model).unwrap(), b"v 0 0 0\n");
}
