//! Each message touchfem uses, both ways: ours serialized and parsed with the `haply` crate's
//! types, and the crate's serialized and parsed with ours; the fields compared.

use haply::device_model::{
    Inverse3Device, Inverse3Message, Inverse3State as TheirState, Inverse3Status as TheirStatus,
    ServiceData, ServiceState, Vec3D,
};
use haply::{Inverse3Commands as TheirCommands, Inverse3OutMsg, ServiceMsg, SetCursorForceCmd};
use haply_wire_check::wire::*;

fn v(x: f32, y: f32, z: f32) -> Vec3D {
    Vec3D { x, y, z }
}

fn ours_update(session: Option<u64>) -> ServiceUpdate {
    ServiceUpdate {
        session_id: session,
        inverse3: vec![Inverse3Entry {
            device_id: "049D".into(),
            state: Inverse3State {
                cursor_position: Some(Vec3::new([0.25, -0.125, 0.5])),
                cursor_velocity: Some(Vec3::new([0.0, 1.0, -2.0])),
                mode: "position".into(),
            },
            status: Inverse3Status {
                calibrated: true,
                in_use: true,
                power_supply: true,
                ready: true,
                started: false,
            },
        }],
    }
}

fn their_state() -> TheirState {
    TheirState {
        cursor_position: Some(v(0.25, -0.125, 0.5)),
        cursor_velocity: Some(v(0.0, 1.0, -2.0)),
        ..TheirState::default()
    }
}

#[test]
fn the_inventory_both_ways() {
    // Ours → theirs (`ServiceData`, what the crate reads on connect).
    let text = serde_json::to_string(&ours_update(Some(7))).unwrap();
    let theirs: ServiceData = serde_json::from_str(&text).unwrap();
    assert_eq!(theirs.session_id, 7);
    let d = &theirs.inverse3[0];
    assert_eq!(d.device_id, "049D");
    assert_eq!(d.state.cursor_position, Some(v(0.25, -0.125, 0.5)));
    assert_eq!(d.state.cursor_velocity, Some(v(0.0, 1.0, -2.0)));
    assert!(d.status.calibrated && d.status.ready && !d.status.started);
    // Theirs (with a full `config`, which we do not read) → ours.
    let theirs = ServiceData {
        session_id: 7,
        inverse3: vec![Inverse3Device {
            device_id: "049D".into(),
            config: Some(Default::default()),
            state: their_state(),
            status: TheirStatus {
                calibrated: true,
                ..Default::default()
            },
        }],
        ..Default::default()
    };
    let ours: ServiceUpdate =
        serde_json::from_str(&serde_json::to_string(&theirs).unwrap()).unwrap();
    assert_eq!(ours.session_id, Some(7));
    assert_eq!(ours.cursor_of("049D"), Some([0.25, -0.125, 0.5]));
    assert!(ours.inverse3[0].status.calibrated);
}

#[test]
fn a_state_update_both_ways() {
    let text = serde_json::to_string(&ours_update(None)).unwrap();
    let theirs: ServiceState = serde_json::from_str(&text).unwrap();
    assert_eq!(theirs.inverse3[0].device_id, "049D");
    assert_eq!(
        theirs.inverse3[0].state.cursor_position,
        Some(v(0.25, -0.125, 0.5))
    );
    let theirs = ServiceState {
        inverse3: vec![Inverse3Message {
            device_id: "049D".into(),
            state: their_state(),
            status: Default::default(),
        }],
        ..ServiceState::default()
    };
    let ours: ServiceUpdate =
        serde_json::from_str(&serde_json::to_string(&theirs).unwrap()).unwrap();
    assert_eq!(ours.cursor_of("049D"), Some([0.25, -0.125, 0.5]));
    assert_eq!(ours.inverse3[0].state.mode, "idle");
}

#[test]
fn set_cursor_force_both_ways() {
    // Ours → theirs. The crate's `ServiceMsg` cannot read its own output (it omits empty
    // `verse_grip` and `wireless_verse_grip` when writing but requires them when reading), so
    // ours is read with those two empty lanes added — the only difference — and also compared
    // byte for byte with what the crate writes below.
    let ours = ClientMessage::cursor_force("049D", [1.5, -0.25, 3.0]);
    let mut value = serde_json::to_value(&ours).unwrap();
    value["verse_grip"] = serde_json::json!([]);
    value["wireless_verse_grip"] = serde_json::json!([]);
    let theirs: ServiceMsg = serde_json::from_value(value).unwrap();
    let cmd = theirs.inverse3[0]
        .commands
        .as_ref()
        .unwrap()
        .set_cursor_force
        .unwrap();
    assert_eq!(theirs.inverse3[0].device_id, "049D");
    assert_eq!(cmd.vector, v(1.5, -0.25, 3.0));
    assert!(cmd.execute);
    assert!(theirs.session.force_render_full_state.is_none() && theirs.session.configure.is_none());
    // The crate's message (as `HaplyDevice` sends it) → ours.
    let mut theirs = ServiceMsg::default();
    theirs.session.force_render_full_state = None;
    theirs.inverse3.push(Inverse3OutMsg {
        device_id: "049D".into(),
        commands: Some(TheirCommands {
            set_cursor_force: Some(SetCursorForceCmd {
                vector: v(1.5, -0.25, 3.0),
                execute: true,
            }),
            ..Default::default()
        }),
        configure: None,
    });
    let text = serde_json::to_string(&theirs).unwrap();
    let back: ClientMessage = serde_json::from_str(&text).unwrap();
    assert_eq!(back.force_for("049D"), Some([1.5, -0.25, 3.0]));
    assert_eq!(
        serde_json::to_string(&back).unwrap(),
        text,
        "the same bytes"
    );
    assert_eq!(
        serde_json::to_string(&ours).unwrap(),
        text,
        "ours writes the crate's bytes"
    );
    // The pre-3.5 name `values` is read too.
    let old = text.replace("\"vector\"", "\"values\"");
    let back: ClientMessage = serde_json::from_str(&old).unwrap();
    assert_eq!(back.force_for("049D"), Some([1.5, -0.25, 3.0]));
}
