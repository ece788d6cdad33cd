//! The viewer's memory: scene edits to undo and redo (Ctrl+Z, Ctrl+Shift+Z), and the files opened recently.
//!
//! A continuous gesture (a slider or an ROI dragged with the mouse held) is one step: its intermediate scenes
//! are not kept. Recent files persist across runs in `recent.txt` under the user's configuration folder.

use std::path::{Path, PathBuf};

use bevy::prelude::Resource;

use fascicle_scene::model::Scene;

/// Scenes before and after the edits made so far.
#[derive(Resource, Debug, Default)]
pub struct SceneHistory {
    undo: Vec<Scene>,
    redo: Vec<Scene>,
    /// The scene as last seen.
    last: Option<Scene>,
    /// The last change was part of a gesture still going on.
    in_gesture: bool,
}

/// Steps kept to undo.
pub const HISTORY_STEPS: usize = 100;

impl SceneHistory {
    /// Notes the scene as it is now; a change since the last call is a step to undo, unless it continues the
    /// gesture (`gesture`: the mouse is held) that made the previous change.
    pub fn record(&mut self, scene: &Scene, gesture: bool) {
        let Some(last) = &self.last else {
            self.last = Some(scene.clone());
            return;
        };
        if last == scene {
            self.in_gesture &= gesture;
            return;
        }
        if !(self.in_gesture && gesture) {
            self.undo.push(last.clone());
            if self.undo.len() > HISTORY_STEPS {
                self.undo.remove(0);
            }
            self.redo.clear();
        }
        self.in_gesture = gesture;
        self.last = Some(scene.clone());
    }

    /// The scene before the last step (`current` goes to the redo list), if any.
    pub fn undo(&mut self, current: &Scene) -> Option<Scene> {
        let previous = self.undo.pop()?;
        self.redo.push(current.clone());
        self.last = Some(previous.clone());
        self.in_gesture = false;
        Some(previous)
    }

    /// The scene the last undo left, if no edit came since.
    pub fn redo(&mut self, current: &Scene) -> Option<Scene> {
        let next = self.redo.pop()?;
        self.undo.push(current.clone());
        self.last = Some(next.clone());
        self.in_gesture = false;
        Some(next)
    }

    /// Whether there is a step to undo.
    pub fn can_undo(&self) -> bool {
        !self.undo.is_empty()
    }

    /// Whether there is an undone step to redo (no edit came since the undo).
    pub fn can_redo(&self) -> bool {
        !self.redo.is_empty()
    }
}

/// Files opened recently, newest first, kept in `path` (none: in memory only).
#[derive(Resource, Debug, Default)]
pub struct RecentFiles {
    /// The files, newest first, at most [`RECENT_FILES`] (canonical paths where [`RecentFiles::add`] could
    /// make them so).
    pub files: Vec<PathBuf>,
    path: Option<PathBuf>,
}

/// Files kept in the recent list.
pub const RECENT_FILES: usize = 12;

impl RecentFiles {
    /// The list kept in `path`: what it holds (a missing or unreadable file is an empty list).
    pub fn load(path: PathBuf) -> Self {
        let files = std::fs::read_to_string(&path)
            .map(|t| t.lines().filter(|l| !l.trim().is_empty()).map(PathBuf::from).take(RECENT_FILES).collect())
            .unwrap_or_default();
        RecentFiles { files, path: Some(path) }
    }

    /// The user's list: `$XDG_CONFIG_HOME/fascicle/recent.txt` or `~/.config/fascicle/recent.txt`.
    pub fn for_user() -> Self {
        let base = std::env::var_os("XDG_CONFIG_HOME")
            .map(PathBuf::from)
            .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".config")));
        match base {
            Some(b) => RecentFiles::load(b.join("fascicle").join("recent.txt")),
            None => RecentFiles::default(),
        }
    }

    /// Puts `file` first (once) and saves the list; a list that cannot be saved stays in memory (the message
    /// says why).
    pub fn add(&mut self, file: &Path) -> Result<(), String> {
        let file = std::fs::canonicalize(file).unwrap_or_else(|_| file.to_path_buf());
        self.files.retain(|f| *f != file);
        self.files.insert(0, file);
        self.files.truncate(RECENT_FILES);
        let Some(path) = &self.path else { return Ok(()) };
        let text: String = self.files.iter().map(|f| format!("{}\n", f.display())).collect();
        path.parent()
            .map_or(Ok(()), std::fs::create_dir_all)
            .and_then(|()| std::fs::write(path, text))
            .map_err(|e| format!("recent files not saved to {}: {e}", path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with_opacity(scene: &Scene, opacity: f32) -> Scene {
        let mut s = scene.clone();
        s.layers[0].opacity = opacity;
        s
    }

    /// Each edit is a step; a drag (mouse held) is one step however many scenes it passes through; undo and
    /// redo walk the steps both ways; a new edit after an undo drops what could be redone.
    #[test]
    fn edits_undo_and_redo_by_step() {
        let s0 = Scene::default_scene();
        let mut h = SceneHistory::default();
        h.record(&s0, false);
        assert!(!h.can_undo());
        let s1 = with_opacity(&s0, 0.5);
        h.record(&s1, false);
        // A drag through three scenes, then the button is released.
        let (d1, d2, d3) = (with_opacity(&s0, 0.4), with_opacity(&s0, 0.3), with_opacity(&s0, 0.2));
        for s in [&d1, &d2, &d3] {
            h.record(s, true);
        }
        h.record(&d3, false);
        assert_eq!(h.undo(&d3).as_ref(), Some(&s1), "the drag is one step");
        assert_eq!(h.undo(&s1).as_ref(), Some(&s0));
        assert_eq!(h.undo(&s0), None);
        assert_eq!(h.redo(&s0).as_ref(), Some(&s1));
        // The undone scene is current again: recording it is not a new step.
        h.record(&s1, false);
        assert_eq!(h.redo(&s1).as_ref(), Some(&d3));
        assert_eq!(h.undo(&d3).as_ref(), Some(&s1));
        let other = with_opacity(&s0, 0.9);
        h.record(&s1, false);
        h.record(&other, false);
        assert!(!h.can_redo(), "a new edit drops the redo list");
        assert_eq!(h.undo(&other).as_ref(), Some(&s1));
        // Two drags one after the other (released in between) are two steps.
        let mut h = SceneHistory::default();
        h.record(&s0, false);
        h.record(&d1, true);
        h.record(&d1, false);
        h.record(&d2, true);
        h.record(&d2, false);
        assert_eq!(h.undo(&d2).as_ref(), Some(&d1));
    }

    /// The newest file first, each once, at most `RECENT_FILES`, kept across runs in the file.
    #[test]
    fn recent_files_persist_newest_first() {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-recent-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let store = dir.join("cfg").join("recent.txt");
        let mut r = RecentFiles::load(store.clone());
        assert!(r.files.is_empty());
        let files: Vec<PathBuf> = (0..15).map(|i| dir.join(format!("f{i}.nii.gz"))).collect();
        for f in &files {
            r.add(f).unwrap();
        }
        r.add(&files[5]).unwrap();
        let again = RecentFiles::load(store);
        assert_eq!(again.files.len(), RECENT_FILES);
        assert_eq!(again.files[0], files[5]);
        assert_eq!(again.files[1], files[14]);
        assert_eq!(again.files.iter().filter(|f| **f == files[5]).count(), 1);
    }
}
