//! The endpoint and topic tables: the whole interface at a glance.

use postcard_rpc::{endpoints, topics, TopicDirection};

use crate::*;

/// Reply of every lighting endpoint.
pub type LitResult = Result<Lit, DeviceError>;
/// Reply of [`BudgetEndpoint`].
pub type BudgetResult = Result<BudgetConfig, DeviceError>;
/// Reply of [`SequenceDefineEndpoint`] and [`SequenceAbortEndpoint`].
pub type StatusResult = Result<SequenceStatus, DeviceError>;
/// Reply of [`SequenceStepsEndpoint`].
pub type StepsResult = Result<StepsLoaded, DeviceError>;
/// Request of [`GammaEndpoint`]: gamma correction on or off, `None` to only ask.
pub type GammaRequest = Option<bool>;
/// Reply of [`GammaEndpoint`]: whether gamma correction is on (after the change).
pub type GammaResult = Result<bool, DeviceError>;
/// Reply of [`SequenceStartEndpoint`].
pub type StartResult = Result<SequenceStarted, DeviceError>;
/// Reply of [`LedSetDefineEndpoint`].
pub type LedSetsResult = Result<LedSetsDefined, DeviceError>;
/// Reply of [`BootselEndpoint`]: sent, then every LED off, then the board restarts in
/// the RP2040 boot ROM's USB mode (BOOTSEL: its RPI-RP2 drive and PICOBOOT), as if
/// BOOTSEL had been held while plugging it in. The link closes with the restart.
pub type BootselResult = Result<(), DeviceError>;

endpoints! {
    list = ENDPOINT_LIST;
    | EndpointTy             | RequestTy         | ResponseTy        | Path                     |
    | ----------             | ---------         | ----------        | ----                     |
    | VersionEndpoint        | ()                | ProtocolVersion   | "fpm/version"            |
    | InfoEndpoint           | ()                | DeviceInfo        | "fpm/info"               |
    | StatusEndpoint         | ()                | DeviceStatus      | "fpm/status"             |
    | SetLedEndpoint         | SetLed            | LitResult         | "fpm/light/led"          |
    | SetLedsEndpoint        | SetLeds           | LitResult         | "fpm/light/leds"         |
    | ClearEndpoint          | ()                | LitResult         | "fpm/light/clear"        |
    | PatternEndpoint        | PatternRequest    | LitResult         | "fpm/light/pattern"      |
    | BrightnessEndpoint     | u8                | LitResult         | "fpm/light/brightness"   |
    | BudgetEndpoint         | BudgetConfig      | BudgetResult      | "fpm/light/budget"       |
    | SequenceDefineEndpoint | SequenceDefine    | StatusResult      | "fpm/seq/define"         |
    | SequenceStepsEndpoint  | StepChunk         | StepsResult       | "fpm/seq/steps"          |
    | SequenceStartEndpoint  | u32               | StartResult       | "fpm/seq/start"          |
    | SequenceAbortEndpoint  | ()                | StatusResult      | "fpm/seq/abort"          |
    | SequenceStatusEndpoint | ()                | SequenceStatus    | "fpm/seq/status"         |
    // 1.1
    | GeometryEndpoint       | ()                | StoredCalibration | "fpm/board/geometry"     |
    | GeometrySetEndpoint    | CalibrationUpdate | StoreResult       | "fpm/board/geometry/set" |
    | GammaEndpoint          | GammaRequest      | GammaResult       | "fpm/light/gamma"        |
    // 1.2
    | LedSetDefineEndpoint   | LedSetDefine      | LedSetsResult     | "fpm/light/set/define"   |
    | SequenceSetStepsEndpoint | SetStepChunk    | StepsResult       | "fpm/seq/set-steps"      |
    // 1.3
    | BootselEndpoint        | ()                | BootselResult     | "fpm/device/bootsel"     |
}

topics! {
    list = TOPICS_OUT_LIST;
    direction = TopicDirection::ToClient;
    | TopicTy          | MessageTy   | Path           |
    | -------          | ---------   | ----           |
    | StepTopic        | StepEvent   | "fpm/seq/step" |
    | SequenceEndTopic | SequenceEnd | "fpm/seq/end"  |
    // 1.2
    | SetStepTopic     | SetStepEvent | "fpm/seq/set-step" |
}

topics! {
    list = TOPICS_IN_LIST;
    direction = TopicDirection::ToServer;
    | TopicTy | MessageTy | Path |
    | ------- | --------- | ---- |
}

#[cfg(test)]
mod tests {
    use super::*;
    use postcard_rpc::{Endpoint, Key, Topic};

    /// Keys must be unique even in their shortest (1-byte) form would be nice, but the
    /// device always answers with 8-byte keys; what matters is that no two request or
    /// message keys collide at 8 bytes.
    #[test]
    fn keys_are_unique() {
        let mut keys: [Key; 23] = [
            VersionEndpoint::REQ_KEY,
            InfoEndpoint::REQ_KEY,
            StatusEndpoint::REQ_KEY,
            SetLedEndpoint::REQ_KEY,
            SetLedsEndpoint::REQ_KEY,
            ClearEndpoint::REQ_KEY,
            PatternEndpoint::REQ_KEY,
            BrightnessEndpoint::REQ_KEY,
            BudgetEndpoint::REQ_KEY,
            SequenceDefineEndpoint::REQ_KEY,
            SequenceStepsEndpoint::REQ_KEY,
            SequenceStartEndpoint::REQ_KEY,
            SequenceAbortEndpoint::REQ_KEY,
            SequenceStatusEndpoint::REQ_KEY,
            GeometryEndpoint::REQ_KEY,
            GeometrySetEndpoint::REQ_KEY,
            GammaEndpoint::REQ_KEY,
            LedSetDefineEndpoint::REQ_KEY,
            SequenceSetStepsEndpoint::REQ_KEY,
            BootselEndpoint::REQ_KEY,
            StepTopic::TOPIC_KEY,
            SetStepTopic::TOPIC_KEY,
            SequenceEndTopic::TOPIC_KEY,
        ];
        keys.sort_by_key(|k| k.to_bytes());
        for pair in keys.windows(2) {
            assert_ne!(pair[0].to_bytes(), pair[1].to_bytes());
        }
        assert_eq!(
            ENDPOINT_LIST.endpoints.len(),
            20 + 2,
            "20 ours + 2 standard"
        );
    }

    /// The version endpoint is frozen: if this key changes, old hosts can no longer ask
    /// new firmware which protocol it speaks.
    #[test]
    fn version_endpoint_is_frozen() {
        assert_eq!(
            VersionEndpoint::REQ_KEY.to_bytes(),
            Key::for_path::<()>("fpm/version").to_bytes()
        );
        assert_eq!(
            VersionEndpoint::RESP_KEY.to_bytes(),
            Key::for_path::<ProtocolVersion>("fpm/version").to_bytes()
        );
    }

    /// Old hosts keep working with new firmware only if the keys of what they use never
    /// change: these are the 1.0 keys (request, response, topic), as a 1.0 host sends
    /// and expects them. A change to any message type they carry changes its key.
    #[test]
    fn keys_of_protocol_1_0_are_unchanged() {
        let pinned: [([u8; 8], [u8; 8]); 6] = [
            (
                InfoEndpoint::REQ_KEY.to_bytes(),
                [0x4c, 0x94, 0x95, 0x08, 0xae, 0x58, 0x33, 0x4a],
            ),
            (
                InfoEndpoint::RESP_KEY.to_bytes(),
                [0x7b, 0xf5, 0x9c, 0x9a, 0xb9, 0x70, 0x42, 0x76],
            ),
            (
                SetLedEndpoint::REQ_KEY.to_bytes(),
                [0x28, 0x6f, 0x25, 0x7d, 0x7b, 0x09, 0x4f, 0xc4],
            ),
            (
                SetLedEndpoint::RESP_KEY.to_bytes(),
                [0x87, 0xd6, 0x50, 0x0c, 0x94, 0xbb, 0x4d, 0xed],
            ),
            (
                SequenceStepsEndpoint::REQ_KEY.to_bytes(),
                [0xd5, 0x22, 0x7a, 0xc0, 0xb1, 0xe4, 0xfd, 0x01],
            ),
            (
                StepTopic::TOPIC_KEY.to_bytes(),
                [0xf7, 0x19, 0xef, 0x75, 0xe7, 0x5a, 0xc7, 0xf8],
            ),
        ];
        for (i, (now, then)) in pinned.iter().enumerate() {
            assert_eq!(
                now, then,
                "key {i} changed: a 1.0 host would no longer be understood"
            );
        }
    }

    #[test]
    fn largest_messages_fit_a_frame() {
        use crate::limits::*;
        let step = Step {
            illumination: Illumination::Pattern(Pattern::Annulus {
                inner: 0.5,
                outer: 0.9,
            }),
            color: Rgb::WHITE,
        };
        let mut steps = heapless::Vec::new();
        for _ in 0..MAX_STEPS_PER_CHUNK {
            steps.push(step).unwrap();
        }
        let chunk = StepChunk {
            id: u32::MAX,
            offset: u16::MAX,
            steps,
        };
        let mut buf = [0u8; MAX_FRAME_LEN];
        let used = postcard::to_slice(&chunk, &mut buf)
            .expect("chunk fits")
            .len();
        // 1 discriminant + 8 key + 4 sequence number
        assert!(used + 13 <= MAX_FRAME_LEN, "chunk takes {used} bytes");

        let mut leds = heapless::Vec::new();
        for i in 0..MAX_LEDS_PER_LIST {
            leds.push(LedIndex::new(i as u8, 255)).unwrap();
        }
        let set = LedSetDefine {
            index: u16::MAX,
            leds: leds.clone(),
        };
        let used = postcard::to_slice(&set, &mut buf).expect("set fits").len();
        assert!(used + 13 <= MAX_FRAME_LEN, "set takes {used} bytes");
        let mut set_steps = heapless::Vec::new();
        for _ in 0..MAX_STEPS_PER_CHUNK {
            set_steps
                .push(SetStep {
                    set: u16::MAX,
                    color: Rgb::WHITE,
                })
                .unwrap();
        }
        let chunk = SetStepChunk {
            id: u32::MAX,
            offset: u16::MAX,
            steps: set_steps,
        };
        let used = postcard::to_slice(&chunk, &mut buf)
            .expect("set chunk fits")
            .len();
        assert!(used + 13 <= MAX_FRAME_LEN, "set chunk takes {used} bytes");
        let list = SetLeds {
            leds,
            color: Rgb::WHITE,
            keep_others: true,
        };
        let used = postcard::to_slice(&list, &mut buf)
            .expect("list fits")
            .len();
        assert!(used + 13 <= MAX_FRAME_LEN, "list takes {used} bytes");
    }
}
