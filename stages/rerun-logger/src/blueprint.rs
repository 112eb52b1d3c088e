//! The viewer's layout, sent with the recording as its blueprint: a single run's scene, follow
//! view, legend and tabs of time series ([`send_single_run`], with [`log_legend`]), or a
//! comparison's views per group ([`send_grouped`]). Derived from the inputs alone, so that the
//! layout is in place before the first frame.

use imuflow_graph::frames::FrameType;

use crate::plots::group_of;
use crate::skeleton::{
    FOLLOW_ENTITY, FOLLOWED, MOTION_RGB, NETWORK_RGB, TRUTH_BESIDE_M, TRUTH_RGB, VALIDATION_RGB,
};

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
    text.push_str("\n**scene**: the world, floor at y = 0. **follow**: the same, the camera moving with the estimate's pelvis.\n");
    if has("truth") {
        text.push_str("\n**errors** tab: per frame against the truth: SIP error (hips and shoulders, deg), mean joint position error (cm, roots aligned), root distance (m), and the latency from the source to the estimate (ms).\n");
    }
    text.push_str("\nOther tabs: each input's small fields over time (contact and stationary probabilities, root velocity, validation scores, ...). A series that never changes is not logged. Times: `seq` (frame) and `capture_time`.\n");
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

/// The layout of a single run, derived from its inputs: the scene and a view that follows the
/// estimate side by side (with the legend), above tabs of time series: the errors against the truth
/// when there is one, then one tab per input with plotted fields, the joint torques of a physics
/// estimate.
pub(crate) fn send_single_run(
    rec: &rerun::RecordingStream,
    inputs: &[(String, FrameType)],
) -> anyhow::Result<()> {
    use rerun::blueprint::components::PanelState;
    use rerun::blueprint::{
        BarChartView, Blueprint, BlueprintActivation, BlueprintPanel, ContainerLike, Horizontal,
        SelectionPanel, Spatial3DView, Tabs, TextDocumentView, TimePanel, TimeSeriesView, Vertical,
    };
    let has = |name: &str| inputs.iter().any(|(e, _)| e == name);
    let scene_contents = ["+ /**", "- /plots/**", "- /legend"];
    let mut top: Vec<ContainerLike> = vec![
        Spatial3DView::new("scene")
            .with_origin("/")
            .with_contents(scene_contents)
            .into(),
    ];
    if has(FOLLOWED) {
        top.push(
            Spatial3DView::new("follow")
                .with_origin(format!("/{FOLLOW_ENTITY}"))
                .with_contents(scene_contents)
                .into(),
        );
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
    let mut tabs: Vec<ContainerLike> = Vec::new();
    if has("truth") && has(FOLLOWED) {
        tabs.push(
            Vertical::new([
                TimeSeriesView::new("SIP error vs truth (deg)")
                    .with_contents([format!("+ /plots/error_vs_truth/{FOLLOWED}/sip_deg")])
                    .into(),
                TimeSeriesView::new("joint position error vs truth (cm)")
                    .with_contents([format!(
                        "+ /plots/error_vs_truth/{FOLLOWED}/joint_position_cm"
                    )])
                    .into(),
                TimeSeriesView::new("root distance from truth (m)")
                    .with_contents([format!(
                        "+ /plots/error_vs_truth/{FOLLOWED}/root_distance_m"
                    )])
                    .into(),
                TimeSeriesView::new("latency, source to estimate (ms)")
                    .with_contents(["+ /plots/latency_ms/**"])
                    .into(),
            ])
            .with_name("errors")
            .into(),
        );
    }
    for (name, frame) in inputs {
        let plotted = match frame {
            FrameType::Imu | FrameType::BodyImu => "IMU signals",
            FrameType::Motion if name == "truth" => continue,
            _ => "fields",
        };
        let series = TimeSeriesView::new(format!("{name}: {plotted}"))
            .with_origin(format!("/plots/{name}"))
            .with_contents(["+ $origin/**"]);
        let tab: ContainerLike = if *frame == FrameType::Motion {
            Horizontal::new([
                series.into(),
                BarChartView::new(format!("{name}: joint torque (N·m)"))
                    .with_origin(format!("/plots/{name}/torque_norm_nm"))
                    .into(),
            ])
            .with_name(name.as_str())
            .into()
        } else {
            Vertical::new([series.into()])
                .with_name(name.as_str())
                .into()
        };
        tabs.push(tab);
    }
    let top: ContainerLike = Horizontal::new(top).with_column_shares(shares).into();
    let root: ContainerLike = if tabs.is_empty() {
        top
    } else {
        Vertical::new([top, Tabs::new(tabs).into()])
            .with_row_shares([3.0, 2.0])
            .into()
    };
    // The views get the screen: the viewer's own side panels start collapsed (a click opens them).
    Blueprint::new(root)
        .with_blueprint_panel(BlueprintPanel::new().with_state(PanelState::Collapsed))
        .with_selection_panel(SelectionPanel::new().with_state(PanelState::Collapsed))
        .with_time_panel(TimePanel::new().with_timeline("seq"))
        .send(rec, BlueprintActivation::default())?;
    Ok(())
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
