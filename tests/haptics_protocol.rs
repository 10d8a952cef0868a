//! The UDP protocol: the worked example of `docs/haptic-protocol.md` is byte for byte what
//! the encoder produces (so the page a driver is written from cannot drift from the code),
//! the documented sizes and offsets hold, and a driver's extrapolation follows the page.

use glam::{DMat3, DVec3};
use palpate::haptics::model::flags;
use palpate::haptics::protocol::{
    ForcePacket, PosePacket, FORCE_LEN, POSE_LEN, POSE_VELOCITY_VALID,
};

const DOC: &str = include_str!("../docs/haptic-protocol.md");

/// The bytes of the hex dump that follows `<!-- example: NAME -->` in the document.
fn example(name: &str) -> Vec<u8> {
    let marker = format!("<!-- example: {name} -->");
    let start = DOC.find(&marker).expect("example marker in the document");
    let block = &DOC[start..];
    let open = block.find("```text\n").expect("a text block") + "```text\n".len();
    let close = block[open..].find("```").expect("end of block") + open;
    let mut bytes = Vec::new();
    for (i, line) in block[open..close].lines().enumerate() {
        let (offset, hex) = line.split_once(':').expect("OFFSET: bytes");
        assert_eq!(
            offset.trim().parse::<usize>().unwrap(),
            16 * i,
            "offset column"
        );
        bytes.extend(
            hex.split_whitespace()
                .map(|h| u8::from_str_radix(h, 16).unwrap()),
        );
    }
    bytes
}

fn example_pose() -> PosePacket {
    PosePacket {
        sequence: 1042,
        device_time: 12.5,
        position: DVec3::new(0.001, -0.002, -0.0035),
        velocity: DVec3::new(0.0, 0.0, -0.05),
        buttons: 1,
        flags: POSE_VELOCITY_VALID,
    }
}

fn example_force() -> ForcePacket {
    ForcePacket {
        sequence: 7,
        echo_sequence: 1042,
        echo_device_time: 12.5,
        time: 3.25,
        force: DVec3::new(0.0, 0.0, 1.25),
        model_force: DVec3::new(0.0, 0.0, 1.25),
        stiffness: DMat3::from_diagonal(DVec3::new(0.0, 0.0, -336.0)),
        model_position: DVec3::new(0.001, -0.002, -0.0035),
        model_age: 0.0021,
        flags: flags::IN_CONTACT,
        max_force: 3.3,
    }
}

#[test]
fn documented_examples_match_the_encoder() {
    let pose = example("pose");
    assert_eq!(pose.len(), POSE_LEN);
    assert_eq!(pose, example_pose().encode().to_vec());
    assert_eq!(PosePacket::decode(&pose), Ok(example_pose()));

    let force = example("force");
    assert_eq!(force.len(), FORCE_LEN);
    assert_eq!(force, example_force().encode().to_vec());
    assert_eq!(ForcePacket::decode(&force), Ok(example_force()));
}

#[test]
fn documented_sizes_and_extrapolation() {
    assert!(DOC.contains("(type 1, driver → palpate, 80 bytes)"));
    assert!(DOC.contains("(type 2, palpate → driver, 208 bytes)"));
    let f = example_force();
    // The page's numbers: 0.1 mm deeper → 1.2836 N.
    let deeper = f.extrapolate(DVec3::new(0.001, -0.002, -0.0036));
    assert!((deeper.z - 1.2836).abs() < 1e-12, "{deeper}");
    // Out of the tissue: no pull.
    assert_eq!(f.extrapolate(DVec3::new(0.0, 0.0, 0.01)), DVec3::ZERO);
    // Far in: clamped to the device's limit, direction kept.
    let far = f.extrapolate(DVec3::new(0.0, 0.0, -0.05));
    assert!((far.length() - 3.3).abs() < 1e-12 && far.x == 0.0 && far.y == 0.0);
    // A pose palpate held back: the force as sent, wherever the driver thinks it is.
    let held = ForcePacket {
        flags: f.flags | flags::POSE_HELD,
        ..f
    };
    assert_eq!(held.extrapolate(DVec3::new(0.0, 0.0, -0.05)), f.force);
}
