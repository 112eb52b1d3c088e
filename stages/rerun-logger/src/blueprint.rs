//! The viewer's layout, sent with the recording as its blueprint: a single run's scene, follow
//! view, legend and tabs of time series ([`send_single_run`], with [`log_legend`]), or a
//! comparison's views per group ([`send_grouped`]). Derived from the inputs, so that the layout is
//! in place before the first frame; a single run's is sent again once a truth pose was logged
//! (the errors tab shows only what a truth gives).

use imuflow_graph::frames::FrameType;
use rerun::external::re_sdk_types::blueprint::archetypes::EyeControls3D;

use crate::plots::group_of;
use crate::skeleton::{
    FOLLOW_ENTITY, FOLLOWED, MOTION_RGB, NETWORK_RGB, TRUTH_BESIDE_M, TRUTH_RGB, VALIDATION_RGB,
};
use crate::stage::APPLICATION_ID;

/// Where the legend (a markdown text document) is logged.
const LEGEND_ENTITY: &str = "legend";

/// Logs a single run's legend ([`legend`]) as a static text document: the blueprint shows it
/// beside the views.
pub(crate) fn log_legend(
    rec: &rerun::RecordingStream,
    inputs: &[(String, FrameType)],
    truth_beside: bool,
) -> anyhow::Result<()> {
    rec.log_static(
        LEGEND_ENTITY,
        &rerun::TextDocument::from_markdown(legend(inputs, truth_beside)),
    )?;
    Ok(())
}

/// The legend of a single run: what each skeleton's colour is, what the views and tabs show.
fn legend(inputs: &[(String, FrameType)], truth_beside: bool) -> String {
    let has = |name: &str| inputs.iter().any(|(e, _)| e == name);
    let mut text = String::from("## imuflow\n\n");
    let truth_text = if truth_beside {
        format!(
            "the true motion's pose, drawn beside the estimate ({TRUTH_BESIDE_M} m along +x from its root; the root's own error is in the errors tab)"
        )
    } else {
        "the true motion, when the source has it".to_owned()
    };
    let skeletons = [
        (
            "motion",
            MOTION_RGB,
            "the estimate: the physics optimizer's output (or the integrated networks without physics); joint spheres grow with joint torque, red arrows are ground-reaction forces",
        ),
        (
            "kinematics",
            NETWORK_RGB,
            "the networks' pose alone, drawn at the estimate's root",
        ),
        ("truth", TRUTH_RGB, truth_text.as_str()),
        (
            "validation",
            VALIDATION_RGB,
            "the rapier simulation that tried to perform the estimate with joint torques only (the judge)",
        ),
    ];
    for (name, rgb, what) in skeletons.iter().filter(|(name, _, _)| has(name)) {
        text.push_str(&format!("- **{}** `{name}`: {what}\n", colour_name(*rgb)));
    }
    if has("contacts") {
        text.push_str("- light blue points and arrows `contacts`: the contacts the physics used, with their forces\n");
    }
    text.push_str("\n**scene**: the floor (y = 0) and the bodies around the estimate, seen from 5 m. **follow**: the same from 2.8 m. Both cameras move with the estimate's pelvis; drag to turn them, scroll to zoom.\n");
    if has("truth") {
        text.push_str("\n**errors** tab (once the source delivers a truth): per frame against the truth: SIP error (hips and shoulders, deg), mean joint position error (cm, roots aligned), root distance (m), and the latency from the source to the estimate (ms).\n");
    }
    text.push_str("\nOther tabs, the estimate's first: each input's small fields over time (contact and stationary probabilities, root velocity, validation scores, ...), an IMU input's sensors as axes beside their signals. A series that never changes is not logged. Times: `seq` (frame) and `capture_time`.\n");
    text
}

/// A fixed colour's name, for the legend.
fn colour_name(rgb: [u8; 3]) -> &'static str {
    match rgb {
        MOTION_RGB => "blue",
        NETWORK_RGB => "pink",
        VALIDATION_RGB => "orange",
        TRUTH_RGB => "green",
        _ => "",
    }
}

/// The 3D views' eyes, in the frame of [`FOLLOW_ENTITY`] (the floor point below the estimate's
/// root, axes as the world's: x left, y up, z forward): each looks at the pelvis's height from
/// its distance, along the direction rerun's own default eye takes in a world of these view
/// coordinates (from behind, left and above). Fixed in that frame, an eye moves with the body: the
/// body keeps one size at every frame of a walk of any length. rerun's default eye instead frames
/// what the view shows at the current frame: with the IMU sensors' axes at the origin that is the
/// whole distance walked (the body a few pixels tall after 12 m), and without them the body alone,
/// so tightly that its feet fall off the view's edge.
const EYE_LOOK_AT_M: [f32; 3] = [0.0, 0.9, 0.0];
/// The follow view's distance: a 1.75 m body with arms and a stride fills about 60 % of its
/// height (rerun's vertical field of view is 55°: at 2.8 m it spans 2.9 m).
const FOLLOW_EYE_DISTANCE_M: f32 = 2.8;
/// The scene's distance: the floor some 2.5 m around the estimate, with the truth, the networks'
/// pose and the forces near it (at 5 m the view spans 5.2 m).
const SCENE_EYE_DISTANCE_M: f32 = 5.0;

/// An eye `distance` m from [`EYE_LOOK_AT_M`]: its position and the point it looks at, in the
/// follow frame (m).
fn eye_at(distance: f32) -> ([f32; 3], [f32; 3]) {
    // rerun 0.36's default eye looks along 0.75 forward + 0.25 right - 0.25 up of the scene; in
    // M (x left, y up, z forward) that is (-0.25, -0.25, 0.75).
    let look = [-0.25f32, -0.25, 0.75];
    let norm = look.iter().map(|v| v * v).sum::<f32>().sqrt();
    let position = std::array::from_fn(|k| EYE_LOOK_AT_M[k] - distance * look[k] / norm);
    (position, EYE_LOOK_AT_M)
}

/// A tab of a single run's time series.
#[derive(Debug, PartialEq)]
enum Tab {
    /// The followed estimate's errors against the truth, and its latency.
    Errors,
    /// An input's own series (and an IMU input's sensors, a physics estimate's torques).
    Input(String, FrameType),
}

/// A single run's tabs, the first one shown when the recording opens: the errors against the truth
/// once a truth pose was logged (an input named `truth` can carry nothing: a file source of real
/// sensors has the port but no truth, and four empty plots would be the first thing a user saw),
/// then the followed estimate's own series, then the other inputs' in input order.
fn single_run_tabs(inputs: &[(String, FrameType)], truth_seen: bool) -> Vec<Tab> {
    let has = |name: &str| inputs.iter().any(|(e, _)| e == name);
    let mut tabs = Vec::new();
    if truth_seen && has("truth") && has(FOLLOWED) {
        tabs.push(Tab::Errors);
    }
    let followed = inputs.iter().filter(|(name, _)| name == FOLLOWED);
    let others = inputs.iter().filter(|(name, _)| name != FOLLOWED);
    for (name, frame) in followed.chain(others) {
        if *frame == FrameType::Motion && name == "truth" {
            continue; // drawn, and measured against in the errors tab
        }
        tabs.push(Tab::Input(name.clone(), *frame));
    }
    tabs
}

/// What the 3D views of a single run show: every drawn body, not the plots, the legend, or the
/// IMU inputs' sensor axes (drawn side by side at the world's origin, they would widen the views'
/// framing by the whole distance walked; they have a view of their own in their input's tab).
fn scene_contents(inputs: &[(String, FrameType)]) -> Vec<String> {
    let mut contents = vec!["+ /**".to_owned(), "- /plots/**".into(), "- /legend".into()];
    for (name, frame) in inputs {
        if matches!(frame, FrameType::Imu | FrameType::BodyImu) {
            contents.push(format!("- /{name}/**"));
        }
    }
    contents
}

/// The errors tab: the followed estimate against the truth (SIP, when its sensors observe the
/// hips and shoulders; joint position and root distance) and its latency from the source.
fn errors_tab(sip: bool) -> rerun::blueprint::ContainerLike {
    use rerun::blueprint::{TimeSeriesView, Vertical};
    let error = |title: &str, series: &str| {
        TimeSeriesView::new(title)
            .with_contents([format!("+ /plots/error_vs_truth/{FOLLOWED}/{series}")])
            .into()
    };
    let mut views = Vec::new();
    if sip {
        views.push(error("SIP error vs truth (deg)", "sip_deg"));
    }
    views.extend([
        error("joint position error vs truth (cm)", "joint_position_cm"),
        error("root distance from truth (m)", "root_distance_m"),
        TimeSeriesView::new("latency, source to estimate (ms)")
            .with_contents(["+ /plots/latency_ms/**"])
            .into(),
    ]);
    Vertical::new(views).with_name("errors").into()
}

/// An input's tab: its plotted series, beside a physics estimate's joint torques or an IMU
/// input's sensor axes.
fn input_tab(name: &str, frame: FrameType) -> rerun::blueprint::ContainerLike {
    use rerun::blueprint::{BarChartView, Horizontal, Spatial3DView, TimeSeriesView, Vertical};
    let plotted = match frame {
        FrameType::Imu | FrameType::BodyImu => "IMU signals",
        _ => "fields",
    };
    let series = TimeSeriesView::new(format!("{name}: {plotted}"))
        .with_origin(format!("/plots/{name}"))
        .with_contents(["+ $origin/**"]);
    match frame {
        FrameType::Motion => Horizontal::new([
            series.into(),
            BarChartView::new(format!("{name}: joint torque (N·m)"))
                .with_origin(format!("/plots/{name}/torque_norm_nm"))
                .into(),
        ])
        .with_name(name)
        .into(),
        // The sensors' axes, side by side: out of the scene (see `scene_contents`).
        FrameType::Imu | FrameType::BodyImu => Horizontal::new([
            Spatial3DView::new(format!("{name}: sensors"))
                .with_origin(format!("/{name}"))
                .with_contents(["+ $origin/**"])
                .into(),
            series.into(),
        ])
        .with_column_shares([1.0, 2.0])
        .with_name(name)
        .into(),
        _ => Vertical::new([series.into()]).with_name(name).into(),
    }
}

/// The layout of a single run, derived from its inputs and whether a truth pose was logged yet:
/// the scene and a view that follows the estimate side by side (with the legend), above tabs of
/// time series ([`single_run_tabs`]). Sent before the first frame, and again when the first truth
/// pose adds the errors tab (the viewer shows the last blueprint sent).
pub(crate) fn send_single_run(
    rec: &rerun::RecordingStream,
    inputs: &[(String, FrameType)],
    truth_seen: bool,
    sip: bool,
) -> anyhow::Result<()> {
    use rerun::blueprint::components::PanelState;
    use rerun::blueprint::{
        Blueprint, BlueprintPanel, ContainerLike, Horizontal, SelectionPanel, Spatial3DView, Tabs,
        TextDocumentView, TimePanel, Vertical,
    };
    let has = |name: &str| inputs.iter().any(|(e, _)| e == name);
    let contents = scene_contents(inputs);
    // Both 3D views have their origin at the entity that moves with the estimate's root, and
    // their eyes fixed in that frame (see `eye_at`); without an estimate, the scene is the world
    // as rerun frames it.
    let mut top: Vec<ContainerLike> = Vec::new();
    let mut eyes = Vec::new();
    let followed = has(FOLLOWED);
    for (name, distance) in [
        ("scene", SCENE_EYE_DISTANCE_M),
        ("follow", FOLLOW_EYE_DISTANCE_M),
    ] {
        if !followed && name == "follow" {
            continue;
        }
        let origin = if followed {
            format!("/{FOLLOW_ENTITY}")
        } else {
            "/".to_owned()
        };
        let view: ContainerLike = Spatial3DView::new(name)
            .with_origin(origin)
            .with_contents(&contents)
            .into();
        if let (true, ContainerLike::View(view)) = (followed, &view) {
            let (position, look_target) = eye_at(distance);
            eyes.push((
                view.blueprint_path(),
                EyeControls3D::new()
                    .with_position(position)
                    .with_look_target(look_target)
                    .with_eye_up([0.0, 1.0, 0.0]),
            ));
        }
        top.push(view);
    }
    top.push(
        TextDocumentView::new("legend")
            .with_origin(format!("/{LEGEND_ENTITY}"))
            .into(),
    );
    let shares: Vec<f32> = match top.len() {
        3 => vec![3.0, 3.0, 1.2],
        _ => vec![5.0, 1.2],
    };
    let tabs: Vec<ContainerLike> = single_run_tabs(inputs, truth_seen)
        .into_iter()
        .map(|tab| match tab {
            Tab::Errors => errors_tab(sip),
            Tab::Input(name, frame) => input_tab(&name, frame),
        })
        .collect();
    let top: ContainerLike = Horizontal::new(top).with_column_shares(shares).into();
    let root: ContainerLike = if tabs.is_empty() {
        top
    } else {
        Vertical::new([top, Tabs::new(tabs).into()])
            .with_row_shares([3.0, 2.0])
            .into()
    };
    // The views get the screen: the viewer's own side panels start collapsed (a click opens them).
    let blueprint = Blueprint::new(root)
        .with_blueprint_panel(BlueprintPanel::new().with_state(PanelState::Collapsed))
        .with_selection_panel(SelectionPanel::new().with_state(PanelState::Collapsed))
        .with_time_panel(TimePanel::new().with_timeline("seq"));
    send_with_eyes(rec, &blueprint, &eyes)
}

/// Sends `blueprint` to `rec` with the given 3D views' eyes (entity path of the view in the
/// blueprint, its eye controls). rerun 0.36's Rust blueprint builder cannot set a view's eye, so
/// the blueprint is built into memory, the eyes are logged into the same blueprint store where the
/// viewer reads a view's properties (`<view path>/EyeControls3D`, as the builder logs the
/// properties it can set), and the whole goes out as one blueprint, activated once complete.
fn send_with_eyes(
    rec: &rerun::RecordingStream,
    blueprint: &rerun::blueprint::Blueprint,
    eyes: &[(rerun::EntityPath, EyeControls3D)],
) -> anyhow::Result<()> {
    let mut messages = blueprint_messages(blueprint)?;
    let Some(rerun::log::LogMsg::BlueprintActivationCommand(activation)) = messages.pop() else {
        anyhow::bail!("rerun's blueprint did not end with its activation");
    };
    let (eye_stream, eye_storage) = rerun::RecordingStreamBuilder::new(APPLICATION_ID)
        .recording_id(activation.blueprint_id.recording_id().clone())
        .blueprint()
        .memory()?;
    // As rerun's blueprint builder: blueprint data is logged at time 0 of `blueprint`.
    eye_stream.set_time_sequence("blueprint", 0);
    for (view, eye) in eyes {
        eye_stream.log(format!("{view}/EyeControls3D"), eye)?;
    }
    eye_stream.flush_blocking()?;
    messages.extend(
        eye_storage
            .take()
            .into_iter()
            .filter(|m| matches!(m, rerun::log::LogMsg::ArrowMsg(..))),
    );
    rec.send_blueprint(messages, activation);
    Ok(())
}

/// The messages rerun's builder sends for `blueprint`, the activation command last: caught in a
/// stream in memory, of which only the blueprint store's messages are kept.
fn blueprint_messages(
    blueprint: &rerun::blueprint::Blueprint,
) -> anyhow::Result<Vec<rerun::log::LogMsg>> {
    let (catcher, storage) = rerun::RecordingStreamBuilder::new(APPLICATION_ID).memory()?;
    blueprint.send(&catcher, rerun::blueprint::BlueprintActivation::default())?;
    catcher.flush_blocking()?;
    Ok(storage
        .take()
        .into_iter()
        .filter(|m| m.store_id().kind() == rerun::StoreKind::Blueprint)
        .collect())
}

/// The layout of a grouped recording: a 3D view per group (each with the truth) or one overlaid
/// view, above time series of the errors against the truth and of the validation scores.
pub(crate) fn send_grouped(
    rec: &rerun::RecordingStream,
    groups: &[String],
    overlaid: bool,
    inputs: &[(String, FrameType)],
) -> anyhow::Result<()> {
    use rerun::blueprint::{
        Blueprint, BlueprintActivation, ContainerLike, Horizontal, Spatial3DView, TimeSeriesView,
        Vertical,
    };
    let has_truth = inputs.iter().any(|(e, _)| e == "truth");
    let shared: Vec<String> = if has_truth {
        vec!["+ /truth/**".into()]
    } else {
        Vec::new()
    };
    let views: Vec<ContainerLike> = if overlaid {
        let mut contents = shared.clone();
        contents.extend(groups.iter().map(|g| format!("+ /{g}/**")));
        vec![
            Spatial3DView::new("all variants")
                .with_origin("/")
                .with_contents(contents)
                .into(),
        ]
    } else {
        groups
            .iter()
            .map(|g| {
                let mut contents = shared.clone();
                contents.push(format!("+ /{g}/**"));
                Spatial3DView::new(g.as_str())
                    .with_origin("/")
                    .with_contents(contents)
                    .into()
            })
            .collect()
    };
    let mut series: Vec<ContainerLike> = Vec::new();
    if has_truth {
        series.push(
            TimeSeriesView::new("joint position error vs truth (cm)")
                .with_contents(
                    groups
                        .iter()
                        .map(|g| format!("+ /plots/error_vs_truth/{g}/joint_position_cm")),
                )
                .into(),
        );
        series.push(
            TimeSeriesView::new("latency, source to motion (ms)")
                .with_contents(["+ /plots/latency_ms/**"])
                .into(),
        );
    } else if let Some(first) = groups.first().filter(|_| groups.len() > 1) {
        series.push(
            TimeSeriesView::new(format!("joint position difference vs {first} (cm)"))
                .with_contents(
                    groups
                        .iter()
                        .skip(1)
                        .map(|g| format!("+ /plots/disagreement_vs_{first}/{g}/joint_position_cm")),
                )
                .into(),
        );
    }
    let validated = inputs
        .iter()
        .any(|(e, f)| *f == FrameType::Validation && group_of(e).is_some());
    if validated {
        let tracking: Vec<String> = groups
            .iter()
            .map(|g| format!("+ /plots/{g}/validation_scores/tracking_error_m"))
            .collect();
        series.push(
            TimeSeriesView::new("validation: tracking error (m)")
                .with_contents(tracking)
                .into(),
        );
    }
    let top: ContainerLike = Horizontal::new(views).into();
    let root: ContainerLike = if series.is_empty() {
        top
    } else {
        Vertical::new([top, Horizontal::new(series).into()]).into()
    };
    Blueprint::new(root).send(rec, BlueprintActivation::default())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use rerun::log::{Chunk, LogMsg};

    use super::*;

    fn inputs(names: &[(&str, FrameType)]) -> Vec<(String, FrameType)> {
        names.iter().map(|(n, f)| (n.to_string(), *f)).collect()
    }

    /// The sample graph's inputs, by name (as the graph lists them).
    fn sample() -> Vec<(String, FrameType)> {
        inputs(&[
            ("contacts", FrameType::Contact),
            ("imu", FrameType::Imu),
            ("kinematics", FrameType::Kinematics),
            ("motion", FrameType::Motion),
            ("truth", FrameType::Motion),
        ])
    }

    fn names(tabs: &[Tab]) -> Vec<String> {
        tabs.iter()
            .map(|t| match t {
                Tab::Errors => "errors".to_owned(),
                Tab::Input(name, _) => name.clone(),
            })
            .collect()
    }

    #[test]
    fn without_a_truth_pose_the_first_tab_is_the_estimates_own() {
        // A truth input that carried nothing (a file of real sensors): no errors tab.
        let tabs = single_run_tabs(&sample(), false);
        assert_eq!(names(&tabs), ["motion", "contacts", "imu", "kinematics"]);
        // No truth input at all: the same.
        let no_truth: Vec<_> = sample().into_iter().filter(|(n, _)| n != "truth").collect();
        assert_eq!(names(&single_run_tabs(&no_truth, true)), names(&tabs));
    }

    #[test]
    fn with_a_truth_pose_the_errors_come_first() {
        let tabs = single_run_tabs(&sample(), true);
        assert_eq!(
            names(&tabs),
            ["errors", "motion", "contacts", "imu", "kinematics"]
        );
        // Errors are measured on the followed estimate: without one, there are none.
        let no_estimate = inputs(&[("imu", FrameType::Imu), ("truth", FrameType::Motion)]);
        assert_eq!(names(&single_run_tabs(&no_estimate, true)), ["imu"]);
    }

    #[test]
    fn the_3d_views_leave_the_sensor_axes_to_their_tab() {
        let contents = scene_contents(&sample());
        assert_eq!(contents, ["+ /**", "- /plots/**", "- /legend", "- /imu/**"]);
    }

    #[test]
    fn the_follow_eye_looks_at_the_pelvis_from_behind_left_above() {
        let (position, look_target) = eye_at(FOLLOW_EYE_DISTANCE_M);
        assert_eq!(look_target, [0.0, 0.9, 0.0]);
        // Hand-derived: (-0.25, -0.25, 0.75) has length sqrt(0.6875) = 0.829156; 2.8 m back along
        // it from (0, 0.9, 0): x = 2.8 * 0.25 / 0.829156 = 0.844232, y = 0.9 + 0.844232,
        // z = -2.8 * 0.75 / 0.829156 = -2.532696.
        let expected = [0.844232, 1.744232, -2.532696];
        for k in 0..3 {
            assert!(
                (position[k] - expected[k]).abs() < 1e-5,
                "{position:?} != {expected:?}"
            );
        }
    }

    /// Every cell of the blueprint store's chunks: (entity path, component, value as text), and
    /// whether the blueprint ends with its activation.
    fn sent_blueprint(
        inputs: &[(String, FrameType)],
        truth_seen: bool,
    ) -> Vec<(String, String, String)> {
        sent_blueprint_with(inputs, truth_seen, true)
    }

    fn sent_blueprint_with(
        inputs: &[(String, FrameType)],
        truth_seen: bool,
        sip: bool,
    ) -> Vec<(String, String, String)> {
        let (rec, storage) = rerun::RecordingStreamBuilder::new(APPLICATION_ID)
            .memory()
            .expect("memory recording");
        send_single_run(&rec, inputs, truth_seen, sip).expect("sent");
        rec.flush_blocking().expect("flushed");
        let messages: Vec<LogMsg> = storage
            .take()
            .into_iter()
            .filter(|m| m.store_id().kind() == rerun::StoreKind::Blueprint)
            .collect();
        let Some(LogMsg::BlueprintActivationCommand(activation)) = messages.last() else {
            panic!("the blueprint does not end with its activation");
        };
        let mut cells = Vec::new();
        for message in &messages {
            assert_eq!(
                message.store_id(),
                &activation.blueprint_id,
                "one blueprint store"
            );
            let LogMsg::ArrowMsg(_, arrow) = message else {
                continue;
            };
            let chunk = Chunk::from_arrow_msg(arrow).expect("a chunk");
            for column in chunk.components().0.values() {
                for row in 0..chunk.num_rows() {
                    cells.push((
                        chunk.entity_path().to_string(),
                        column.descriptor.component.to_string(),
                        format!("{:?}", column.list_array.value(row)),
                    ));
                }
            }
        }
        cells
    }

    #[test]
    fn the_3d_views_eyes_are_in_the_blueprint_that_is_activated() {
        let cells = sent_blueprint(&sample(), false);
        // The view each eye belongs to: its name and origin, and the eye's position.
        let mut eyes = Vec::new();
        for (entity, component, value) in &cells {
            if !(entity.ends_with("/EyeControls3D") && component.ends_with(":position")) {
                continue;
            }
            let view = entity.trim_end_matches("/EyeControls3D");
            let of_view = |suffix: &str| {
                cells
                    .iter()
                    .find(|(e, c, _)| e == view && c.ends_with(suffix))
                    .map(|(_, _, v)| v.clone())
                    .expect("the eye's view")
            };
            // The decimals in the cell's text (its type names `3` and `32` are not values).
            let position: Vec<f32> = value
                .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-'))
                .filter(|t| t.contains('.'))
                .filter_map(|t| t.parse().ok())
                .collect();
            eyes.push((of_view("display_name"), of_view("space_origin"), position));
        }
        eyes.sort_by(|a, b| a.0.cmp(&b.0));
        assert_eq!(eyes.len(), 2, "{eyes:?}");
        for ((name, origin, position), (expected_name, distance)) in eyes.iter().zip([
            ("follow", FOLLOW_EYE_DISTANCE_M),
            ("scene", SCENE_EYE_DISTANCE_M),
        ]) {
            assert!(name.contains(expected_name), "{name}");
            assert!(origin.contains("/follow"), "{origin}");
            assert_eq!(position.as_slice(), eye_at(distance).0, "{name}");
        }
        // The errors tab waits for a truth pose.
        let has_errors = |cells: &[(String, String, String)]| {
            cells
                .iter()
                .any(|(_, c, v)| c.ends_with("display_name") && v.contains("\"errors\""))
        };
        assert!(!has_errors(&cells));
        assert!(has_errors(&sent_blueprint(&sample(), true)));
        // A set that observes no shoulder (the lower body) has no SIP plot: it would stay empty.
        let has_sip = |cells: &[(String, String, String)]| {
            cells
                .iter()
                .any(|(_, c, v)| c.ends_with("display_name") && v.contains("SIP error"))
        };
        assert!(has_sip(&sent_blueprint(&sample(), true)));
        assert!(!has_sip(&sent_blueprint_with(&sample(), true, false)));
        // Without an estimate to follow: the world as rerun frames it, no eye set.
        let sensors_only = inputs(&[("imu", FrameType::Imu)]);
        let cells = sent_blueprint(&sensors_only, false);
        assert!(!cells.iter().any(|(e, _, _)| e.ends_with("/EyeControls3D")));
    }
}
