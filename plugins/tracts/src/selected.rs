//! Line meshes of a set's selected streamlines only. The vertex stage runs for every vertex a draw indexes,
//! hidden or not (the tract shaders hide the streamlines a selection leaves out): a 10 mm sphere that keeps
//! 3 % of a 10M-streamline layer left 97 % of each frame's vertex work to streamlines it then hid. So a line
//! set's preview is made again of its selected streamlines at each selection ([`PreviewLines`], kept on the
//! CPU), and, when few are selected, its whole lines are made again of those once the selection rests
//! ([`SelectedLines`], from the set's streamlines). Each draws what the whole mesh draws with the selection's
//! flags: the same vertices, colours and segments of the same streamlines, in the same order.

use bevy::mesh::{PrimitiveTopology, VertexAttributeValues};
use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use std::sync::mpsc::{Receiver, TryRecvError};
use std::sync::{Arc, Mutex};

use crate::{
    ATTRIBUTE_RGBA8, ATTRIBUTE_STREAMLINE, MeshSet, SetStreamlines, TractSelection, TractSet, compact_line_list,
    line_list, write_flags,
};

/// The streamline index a narrowed preview's vertices carry ([`PreviewLines::selected`]): the tract shaders show
/// such a vertex whatever the set's selection flags, so a preview made of the selected streamlines draws
/// without them, and a drag step that such previews show uploads no flags ([`FlagsBehind`]).
pub const UNFLAGGED: u32 = u32::MAX;

/// A line set's whole preview kept on the CPU (at most about [`PREVIEW_SEGMENTS`](crate::PREVIEW_SEGMENTS)
/// segments: some tens of MB), from which the preview mesh the set draws is made of its selected streamlines
/// only ([`narrow_previews`]).
/// The vertex stage runs for every vertex a draw indexes, hidden or not: a 10 mm sphere that keeps 3 % of a
/// 10M-streamline layer left 97 % of each preview frame's vertex work (about 40 ms of a window's ROI drag frame
/// on lavapipe with 2 cores) to streamlines it then hid.
#[derive(Component, Clone, Debug, Default)]
pub struct PreviewLines {
    positions: Vec<[f32; 3]>,
    colours: Vec<[u8; 4]>,
    /// Per preview streamline: its index in the set, its first vertex and its vertex count (a streamline's
    /// kept points are consecutive vertices, joined by the segments between neighbours).
    runs: Vec<(u32, u32, u32)>,
    /// The preview mesh holds fewer than all the preview's streamlines.
    narrowed: bool,
    /// The preview mesh draws without the set's flags (made of the selected streamlines, [`UNFLAGGED`]).
    unflagged: bool,
}

impl PreviewLines {
    /// The preview mesh's vertices and streamlines; `None` unless it is a line list in the compact format with
    /// each streamline's points consecutive (as [`line_mesh_coloured`](crate::line_mesh_coloured) and
    /// [`preview_mesh`](crate::preview_mesh) make it).
    pub fn of(mesh: &Mesh) -> Option<Self> {
        let (
            Some(VertexAttributeValues::Float32x3(positions)),
            Some(VertexAttributeValues::Unorm8x4(colours)),
            Some(VertexAttributeValues::Uint32(ids)),
        ) = (
            mesh.attribute(Mesh::ATTRIBUTE_POSITION),
            mesh.attribute(ATTRIBUTE_RGBA8),
            mesh.attribute(ATTRIBUTE_STREAMLINE),
        )
        else {
            return None;
        };
        if mesh.primitive_topology() != PrimitiveTopology::LineList {
            return None;
        }
        let mut runs: Vec<(u32, u32, u32)> = Vec::new();
        for (v, &id) in ids.iter().enumerate() {
            match runs.last_mut() {
                Some(run) if run.0 == id => run.2 += 1,
                _ => runs.push((id, v as u32, 1)),
            }
        }
        Some(Self { positions: positions.clone(), colours: colours.clone(), runs, narrowed: false, unflagged: false })
    }

    /// The preview of the streamlines `selected` keeps (indexed by streamline in the set), in the format of
    /// [`line_mesh_coloured`](crate::line_mesh_coloured) but each vertex's streamline [`UNFLAGGED`] (it draws
    /// without the set's flags); and whether it is so. With none kept, the first streamline with its index
    /// (hidden by the set's flags, which it then needs), since a mesh is never empty.
    pub fn selected(&self, selected: &[bool]) -> (Mesh, bool) {
        let kept = |&&(id, _, _): &&(u32, u32, u32)| selected.get(id as usize).copied().unwrap_or(false);
        let mut runs: Vec<_> = self.runs.iter().filter(kept).collect();
        let unflagged = !runs.is_empty();
        if runs.is_empty() {
            runs.extend(self.runs.first());
        }
        let n: usize = runs.iter().map(|r| r.2 as usize).sum();
        let (mut pos, mut col, mut ids, mut idx) =
            (Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n), Vec::new());
        for &&(id, first, count) in &runs {
            let base = pos.len() as u32;
            let range = first as usize..(first + count) as usize;
            pos.extend_from_slice(&self.positions[range.clone()]);
            col.extend_from_slice(&self.colours[range]);
            ids.extend(std::iter::repeat_n(if unflagged { UNFLAGGED } else { id }, count as usize));
            idx.extend((0..count.saturating_sub(1)).flat_map(|k| [base + k, base + k + 1]));
        }
        (compact_line_list(pos, ids, col, idx), unflagged)
    }
}

/// Remakes the preview mesh of each line set whose selection changed ([`apply_rois`](crate::apply_rois)) of its
/// selected streamlines ([`PreviewLines::selected`]), drawn in the same frame; a set that arrived in this frame, in the
/// next (its preview's `Added` event is sent then, and would extract the mesh a second time).
pub fn narrow_previews(
    changed: Query<(Entity, Ref<TractSelection>), Changed<TractSelection>>,
    mut sets: Query<(&TractSelection, &MeshSet, &mut PreviewLines)>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut mesh_events: MessageWriter<AssetEvent<Mesh>>,
    mut arrived: Local<Vec<Entity>>,
) {
    let mut due = std::mem::take(&mut *arrived);
    for (e, selection) in &changed {
        if selection.is_added() { arrived.push(e) } else { due.push(e) }
    }
    due.sort_unstable();
    due.dedup();
    for e in due {
        let Ok((selection, set, mut lines)) = sets.get_mut(e) else { continue };
        // A preview that holds every streamline already (a layer without ROIs) is not sent again.
        let all = selection.0.iter().all(|s| *s);
        if all && !lines.narrowed {
            continue;
        }
        lines.narrowed = !all;
        if let Some(preview) = &set.preview {
            let (narrowed, unflagged) = lines.selected(&selection.0);
            lines.unflagged = unflagged;
            fascicle_render::modify_now(&mut meshes, &mut mesh_events, preview, |m| *m = narrowed);
        }
    }
}

/// Whether a line set's selection flags ([`TractSet::selected`]) are behind its [`TractSelection`]. A line set
/// with a preview ([`PreviewLines`]) takes its flags only when it draws a mesh that reads them
/// ([`upload_flags_behind`]): an ROI drag's steps, whose frames draw the narrowed previews ([`UNFLAGGED`]),
/// upload none (at 10M streamlines, 255 buffers a step, each a new GPU buffer and bind group), and the frame
/// that draws the whole sets again uploads each set's flags once.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct FlagsBehind(pub bool);

/// Uploads the flags of the line sets whose flags are behind ([`FlagsBehind`]) and which draw, in this frame, a
/// mesh that reads them: their whole mesh, their selection's lines, or a preview not made of selected
/// streamlines. Runs after the meshes are chosen ([`crate::TractDetail`]); drawn in this frame.
pub fn upload_flags_behind(
    mut sets: Query<(&TractSet, &TractSelection, &MeshSet, &Mesh3d, &PreviewLines, &mut FlagsBehind)>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
    mut buffer_events: MessageWriter<AssetEvent<ShaderBuffer>>,
) {
    for (set, selection, mesh_set, mesh, lines, mut behind) in &mut sets {
        let unflagged = lines.unflagged && mesh_set.preview.as_ref() == Some(&mesh.0);
        if !behind.0 || unflagged {
            continue;
        }
        // Not a change the picture shows (the flags' asset is): a retained picture is not kept from coming back.
        behind.bypass_change_detection().0 = false;
        write_flags(&mut buffers, &mut buffer_events, &set.selected, &selection.0);
    }
}

/// The share of a line set's streamlines selected below which its whole lines are made again of the selected
/// ones ([`SelectedLines`]): an eighth. A mesh of the selection then holds at most an eighth of the whole
/// mesh's vertices, and saves at least seven eighths of its vertex work.
pub const SELECTED_LINES_BELOW: f64 = 0.125;

/// The selected points up to which a set's selected lines are made in the frame that needs them (a few
/// milliseconds); more are made on rayon's pool.
const IN_FRAME_POINTS: usize = 200_000;

/// The whole lines of a line set's selected streamlines, when the selection keeps fewer than
/// [`SELECTED_LINES_BELOW`] of them: made from the set's streamlines ([`TractSet`]) as the whole mesh was
/// (coloured by direction, compressed to the same tolerance: sets coloured otherwise carry none of this), each
/// vertex keeping its streamline's index in the set, so the set's material and flags act on it as on the
/// whole mesh. Made once the selection rests (no frame budget, or the view still: never at each step of an
/// ROI drag, whose frames draw the previews), in the frame for a small selection, otherwise on rayon's pool
/// (every core: no frame is drawn meanwhile); until it is drawn, the whole mesh with the selection's flags
/// draws the same picture (and a viewer with [`crate::TractDetail`] on keeps the preview). The set then draws
/// it where it drew the whole mesh, while the view is still; a new selection drops it at once (its GPU copy
/// goes with it). Not made for tractograms over [`crate::COARSE_DETAIL_POINTS`] ([`crate::LineDetail`]).
#[derive(Component, Default)]
pub struct SelectedLines {
    /// The compression tolerance of the set's whole lines, mm.
    tolerance_mm: f64,
    /// Whether the current selection keeps few enough streamlines for a mesh of its own; `None` until it is
    /// weighed (once the view is still: not at each step of a drag).
    wanted: Option<bool>,
    /// Its mesh being made on rayon's pool, and the token that job holds weakly: dropped when the selection
    /// changes, so that a job not started yet does nothing.
    task: Option<(Mutex<Receiver<Mesh>>, Arc<()>)>,
    /// Its mesh, and whether it can be drawn: the render world has it from the frame after it was added (its
    /// `Added` event is sent then).
    made: Option<(Handle<Mesh>, bool)>,
}

impl SelectedLines {
    /// For a set of lines coloured by direction, compressed to `tolerance_mm`.
    pub fn new(tolerance_mm: f64) -> Self {
        SelectedLines { tolerance_mm, ..default() }
    }

    /// The mesh of the current selection's streamlines, once the render world has it.
    pub fn mesh(&self) -> Option<&Handle<Mesh>> {
        self.made.as_ref().filter(|m| m.1).map(|(h, _)| h)
    }

    /// A mesh of the current selection may be wanted (or is not weighed yet) and cannot be drawn yet.
    pub fn pending(&self) -> bool {
        self.wanted != Some(false) && self.mesh().is_none()
    }
}

/// The lines of the streamlines `selected` keeps of `t` (with none kept, the first streamline of two points or
/// more, which the set's flags hide: a mesh is never empty).
fn selected_lines(t: &SetStreamlines, selected: &[bool], tolerance_mm: f64) -> Mesh {
    let n = t.n_streamlines().min(selected.len());
    let kept = (0..n).filter(|&s| selected[s]).map(|s| (s, t.streamline(s)));
    let mesh = if selected[..n].iter().any(|&k| k) {
        line_list(kept, None, tolerance_mm)
    } else {
        let first = (0..n).find(|&s| t.streamline(s).len() >= 2);
        line_list(first.map(|s| (s, t.streamline(s))).into_iter(), None, tolerance_mm)
    };
    // What the pass read in place goes again.
    t.release();
    mesh
}

/// Keeps each line set's [`SelectedLines`] in step with its selection: a changed selection drops the mesh
/// of the last one (and a build under way) and wants one when it keeps fewer than [`SELECTED_LINES_BELOW`] of
/// the streamlines; a wanted mesh is made once the selection rests: the view is still
/// ([`BudgetState`](fascicle_render::budget::BudgetState), when there is one), or the set's selection did not
/// change in this frame and no layer's is being made ([`RoiStats::pending_layers`](crate::RoiStats)), as
/// after the last step of a drag. It can be drawn the frame after it is added. While any is being made, the
/// interaction that changed the selection is not over ([`Interacting::pending`](fascicle_render::budget::Interacting::pending):
/// its full-quality frame waits for them, and draws once), and a window drawn on demand keeps looking.
#[allow(clippy::type_complexity, reason = "a Bevy system's parameters")]
pub fn make_selected_lines(
    mut sets: Query<(Ref<TractSelection>, &TractSet, &mut SelectedLines)>,
    mut meshes: ResMut<Assets<Mesh>>,
    (budget, stats): (Option<Res<fascicle_render::budget::BudgetState>>, Option<Res<crate::RoiStats>>),
    (mut keep_awake, mut interacting, mut was_making): (
        Option<ResMut<fascicle_render::KeepAwake>>,
        Option<ResMut<fascicle_render::budget::Interacting>>,
        Local<bool>,
    ),
) {
    let still = budget.is_none_or(|b| !b.moving);
    let selecting = stats.is_some_and(|s| s.pending_layers > 0);
    let (mut making, mut landed) = (false, false);
    for (selection, set, mut lines) in &mut sets {
        // Book-keeping only: what the set draws changes with its `Mesh3d` ([`crate::TractDetail`]'s system),
        // and a component changed every frame would keep the retained picture from being put back.
        let lines = lines.bypass_change_detection();
        if let Some(made) = lines.made.as_mut().filter(|m| !m.1) {
            made.1 = true;
            landed = true;
        }
        let changed = selection.is_changed();
        if changed {
            (lines.wanted, lines.task, lines.made) = (None, None, None);
        }
        if (still || (!changed && !selecting)) && lines.wanted.is_none() {
            let kept = selection.0.iter().filter(|s| **s).count();
            lines.wanted = Some((kept as f64) < SELECTED_LINES_BELOW * selection.0.len() as f64);
        }
        if lines.wanted != Some(true) || lines.made.is_some() {
            continue;
        }
        let mut mesh = None;
        if lines.task.is_none() {
            let t = &set.tractogram;
            let points: usize =
                selection.0.iter().enumerate().filter(|(_, k)| **k).map(|(s, _)| t.streamline(s).len()).sum();
            if points <= IN_FRAME_POINTS {
                mesh = Some(selected_lines(t, &selection.0, lines.tolerance_mm));
            } else {
                let (t, selected, tolerance) = (t.clone(), selection.0.clone(), lines.tolerance_mm);
                let (send, done) = std::sync::mpsc::channel();
                let token = Arc::new(());
                let wanted = Arc::downgrade(&token);
                rayon::spawn(move || {
                    // A job that panicked sends nothing (its sender dropped): the whole mesh draws instead.
                    let make = std::panic::AssertUnwindSafe(|| selected_lines(&t, &selected, tolerance));
                    if wanted.strong_count() > 0
                        && let Ok(mesh) = std::panic::catch_unwind(make)
                    {
                        _ = send.send(mesh);
                    }
                });
                lines.task = Some((Mutex::new(done), token));
            }
        }
        let received =
            lines.task.as_ref().map(|(done, _)| done.lock().map_or(Err(TryRecvError::Disconnected), |d| d.try_recv()));
        match received {
            Some(Ok(made)) => {
                lines.task = None;
                mesh = Some(made);
            }
            // The job died: the whole mesh and its flags draw the selection.
            Some(Err(TryRecvError::Disconnected)) => (lines.task, lines.wanted) = (None, Some(false)),
            _ => {}
        }
        if let Some(mesh) = mesh {
            lines.made = Some((meshes.add(mesh), false));
        }
        making |= lines.task.is_some() || lines.made.is_some();
    }
    if making && let Some(interacting) = interacting.as_deref_mut() {
        interacting.pending();
    }
    if let Some(keep) = keep_awake.as_deref_mut() {
        if making {
            keep.busy();
        } else if *was_making || landed {
            keep.redraw();
        }
    }
    *was_making = making;
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use bevy::asset::AssetPlugin;
    use bevy::ecs::system::RunSystemOnce;
    use bevy::mesh::Indices;
    use bevy::render::storage::ShaderBuffer;
    use fascicle_core::io::Tractogram;
    use fascicle_render::budget::{BudgetState, Interacting};

    use super::*;
    use crate::{TractMeshMaterial, line_mesh, spawn_lines};

    /// `n` helices of `points` points at 1 mm steps, side by side.
    fn helices(n: usize, points: usize) -> Tractogram {
        let mut t = Tractogram::new();
        for i in 0..n {
            let s: Vec<Vec3> = (0..points)
                .map(|k| {
                    let a = k as f32 * 0.1;
                    Vec3::new(10.0 * a.cos() + i as f32, 10.0 * a.sin(), 0.5 * k as f32)
                })
                .collect();
            t.push(&s);
        }
        t
    }

    /// Per vertex: position, streamline, colour; and the segments as pairs of vertices.
    type Lines = (Vec<([f32; 3], u32, [u8; 4])>, Vec<[u32; 2]>);

    fn lines(m: &Mesh) -> Lines {
        match (m.attribute(Mesh::ATTRIBUTE_POSITION), m.attribute(ATTRIBUTE_STREAMLINE), m.attribute(ATTRIBUTE_RGBA8)) {
            (
                Some(VertexAttributeValues::Float32x3(p)),
                Some(VertexAttributeValues::Uint32(ids)),
                Some(VertexAttributeValues::Unorm8x4(c)),
            ) => {
                let Some(Indices::U32(idx)) = m.indices() else { panic!("u32 indices") };
                let vertices = (0..p.len()).map(|v| (p[v], ids[v], c[v])).collect();
                (vertices, idx.chunks(2).map(|s| [s[0], s[1]]).collect())
            }
            _ => panic!("a compact line mesh"),
        }
    }

    /// The whole mesh's vertices of the streamlines `keep` selects, and its segments between them (renumbered).
    fn whole_of_selected(whole: &Mesh, keep: &[bool]) -> Lines {
        let (vertices, segments) = lines(whole);
        let mut renumbered = vec![u32::MAX; vertices.len()];
        let mut kept = Vec::new();
        for (v, vertex) in vertices.iter().enumerate().filter(|(_, v)| keep[v.1 as usize]) {
            renumbered[v] = kept.len() as u32;
            kept.push(*vertex);
        }
        let segments = segments
            .iter()
            .filter(|s| keep[vertices[s[0] as usize].1 as usize])
            .map(|s| s.map(|v| renumbered[v as usize]));
        (kept, segments.collect())
    }

    /// An app with a line set of `t` spawned ([`spawn_lines`]: tolerance 0.1 mm) and [`make_selected_lines`].
    fn app_with_lines(t: Tractogram) -> (App, Entity) {
        let mut app = App::new();
        app.add_plugins((MinimalPlugins, AssetPlugin::default()))
            .init_asset::<Mesh>()
            .init_asset::<TractMeshMaterial>()
            .init_asset::<ShaderBuffer>()
            .add_systems(Update, make_selected_lines);
        let t = Arc::new(t);
        let spawn = move |mut commands: Commands,
                          mut meshes: ResMut<Assets<Mesh>>,
                          mut materials: ResMut<Assets<TractMeshMaterial>>,
                          mut buffers: ResMut<Assets<ShaderBuffer>>| {
            spawn_lines(&mut commands, &mut meshes, &mut materials, &mut buffers, t.clone(), 1.0)
        };
        let e = app.world_mut().run_system_once(spawn).expect("spawned");
        app.update();
        (app, e)
    }

    fn select(app: &mut App, e: Entity, keep: &[bool]) {
        app.world_mut().get_mut::<TractSelection>(e).expect("a tract set").0 = keep.to_vec();
    }

    fn selected_mesh(app: &App, e: Entity) -> Option<Mesh> {
        let lines = app.world().get::<SelectedLines>(e).expect("selected lines");
        lines.mesh().map(|h| app.world().resource::<Assets<Mesh>>().get(h).expect("the mesh").clone())
    }

    /// A selection of few streamlines gets lines of its own, drawable the frame after they are made: the whole
    /// mesh's vertices, colours and segments of the selected streamlines, in order. A selection of many, or one
    /// made while the view moves, gets none (until it is still); a new selection drops the last one's.
    #[test]
    fn a_small_selection_has_the_whole_lines_of_its_streamlines() {
        let t = helices(40, 60);
        let whole = line_mesh(&t);
        let (mut app, e) = app_with_lines(t);
        assert!(selected_mesh(&app, e).is_none(), "every streamline selected");
        let keep: Vec<bool> = (0..40).map(|s| [3, 17, 30].contains(&s)).collect();
        select(&mut app, e, &keep);
        app.update();
        assert!(app.world().get::<SelectedLines>(e).unwrap().pending(), "made, drawable in the next frame");
        app.update();
        let mesh = selected_mesh(&app, e).expect("made");
        let expected = whole_of_selected(&whole, &keep);
        assert_eq!(lines(&mesh), expected);
        assert_eq!(crate::line_segments(&mesh), expected.1.len());
        // Frames after it change no component (they would keep a retained picture from being put back).
        let ticks = |app: &App| app.world().entity(e).get_change_ticks::<SelectedLines>().map(|t| t.changed);
        let before = ticks(&app);
        app.update();
        assert_eq!(ticks(&app), before, "the set's selected lines marked changed in a frame that changed nothing");

        // Five of 40 is over an eighth: the whole mesh and its flags.
        let many: Vec<bool> = (0..40).map(|s| s < 5).collect();
        select(&mut app, e, &many);
        app.update();
        let lines_now = app.world().get::<SelectedLines>(e).unwrap();
        assert!(lines_now.mesh().is_none() && !lines_now.pending());

        // While the view moves (a frame budget's drag), nothing is made while the selection changes every frame
        // or a layer's selection is being made; a frame that changes it not, with none being made, makes it, and
        // the interaction is pending until it can be drawn.
        app.insert_resource(BudgetState { moving: true, ..default() }).init_resource::<Interacting>();
        app.insert_resource(crate::RoiStats { pending_layers: 1, ..default() });
        for k in 0..4 {
            if k < 2 {
                select(&mut app, e, if k % 2 == 0 { &keep } else { &many });
            }
            app.update();
            assert!(app.world().get::<SelectedLines>(e).unwrap().mesh().is_none(), "made while selecting ({k})");
        }
        select(&mut app, e, &keep);
        app.update();
        app.world_mut().resource_mut::<crate::RoiStats>().pending_layers = 0;
        app.update();
        assert!(app.world().get::<SelectedLines>(e).unwrap().pending(), "made in the frame the selection rests");
        assert!(app.world().resource::<Interacting>().is_pending(), "the interaction is pending meanwhile");
        app.update();
        assert_eq!(selected_mesh(&app, e).map(|m| lines(&m)), Some(expected));
    }

    /// A selection of more points than a frame makes is made in the background, with the same lines; with
    /// none selected, the first streamline (which the flags hide).
    #[test]
    fn a_large_selection_is_made_in_the_background() {
        let t = helices(2_000, 1_000);
        let whole = line_mesh(&t);
        let (mut app, e) = app_with_lines(t);
        let keep: Vec<bool> = (0..2_000).map(|s| s % 9 == 4).collect();
        assert!(keep.iter().filter(|k| **k).count() * 1_000 > IN_FRAME_POINTS, "more points than a frame makes");
        select(&mut app, e, &keep);
        app.update();
        // Sent to rayon's pool (or, when this thread was descheduled meanwhile, already back from it).
        let lines_now = app.world().get::<SelectedLines>(e).unwrap();
        assert!(lines_now.task.is_some() || lines_now.made.as_ref().is_some_and(|m| !m.1));
        let start = std::time::Instant::now();
        while selected_mesh(&app, e).is_none() && start.elapsed() < std::time::Duration::from_secs(60) {
            std::thread::sleep(std::time::Duration::from_millis(5));
            app.update();
        }
        let mesh = selected_mesh(&app, e).expect("made in the background");
        assert_eq!(lines(&mesh), whole_of_selected(&whole, &keep));

        select(&mut app, e, &[false; 2_000]);
        app.update();
        app.update();
        let (vertices, _) = lines(&selected_mesh(&app, e).expect("made"));
        assert!(!vertices.is_empty() && vertices.iter().all(|v| v.1 == 0), "the first streamline only");
    }
}
