//! Service settings (QoS) of every topic, defined once.
//!
//! iceoryx2 refuses to open a service whose settings differ from the ones it
//! was created with, so every process must ask for exactly these. The stage
//! runtime is the only code that turns them into service builders.

use crate::topics;

/// Settings of one publish-subscribe service.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServiceQos {
    /// Samples a publisher keeps for late subscribers.
    pub history_size: usize,
    /// Samples a subscriber can hold unread.
    pub subscriber_max_buffer_size: usize,
    /// Samples a subscriber may borrow at once.
    pub subscriber_max_borrowed_samples: usize,
    /// Publishers allowed on the service.
    pub max_publishers: usize,
    /// Subscribers allowed on the service.
    pub max_subscribers: usize,
    /// Nodes allowed on the service.
    pub max_nodes: usize,
    /// Overwrite the oldest sample when a subscriber's buffer is full (never
    /// block a publisher on a stalled subscriber).
    pub safe_overflow: bool,
}

/// History kept for late joiners (the logger after a restart): at least 2 s at
/// the highest rate a topic carries (IMU at 1 kHz on real flights).
const IMU_HISTORY: usize = 2048;

/// Base settings; topics override the sizes.
const BASE: ServiceQos = ServiceQos {
    history_size: 64,
    subscriber_max_buffer_size: 256,
    subscriber_max_borrowed_samples: 4,
    max_publishers: 4,
    max_subscribers: 16,
    max_nodes: 24,
    safe_overflow: true,
};

/// The settings of `topic` (one of [`crate::topics`]); unknown topics get the base settings.
#[must_use]
pub fn for_topic(topic: &str) -> ServiceQos {
    match topic {
        topics::IMU | topics::NAV => ServiceQos {
            history_size: IMU_HISTORY,
            subscriber_max_buffer_size: IMU_HISTORY,
            ..BASE
        },
        topics::UWB_TDOA | topics::UWB_RANGE | topics::BODY_VEL => ServiceQos {
            history_size: 1024,
            subscriber_max_buffer_size: 1024,
            ..BASE
        },
        topics::UWB_FIX | topics::FUSED | topics::DIAG | topics::TRUTH => ServiceQos {
            history_size: 512,
            subscriber_max_buffer_size: 512,
            ..BASE
        },
        topics::CORRECTION => ServiceQos {
            history_size: 64,
            subscriber_max_buffer_size: 256,
            ..BASE
        },
        topics::HEALTH => ServiceQos {
            history_size: 16,
            subscriber_max_buffer_size: 256,
            max_publishers: 16,
            ..BASE
        },
        _ => BASE,
    }
}

/// Name of the event service that wakes the subscribers of `topic`.
#[must_use]
pub fn event_name(topic: &str) -> String {
    format!("{topic}.ev")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_topic_keeps_two_seconds_of_its_rate_and_safe_overflow() {
        // IMU at 1 kHz for 2 s.
        assert!(for_topic(topics::IMU).history_size >= 2000);
        // UWB TDOA at ~400 Hz for 2 s.
        assert!(for_topic(topics::UWB_TDOA).history_size >= 800);
        for t in [
            topics::IMU,
            topics::UWB_TDOA,
            topics::UWB_FIX,
            topics::NAV,
            topics::FUSED,
            topics::DIAG,
            topics::CORRECTION,
            topics::HEALTH,
            topics::TRUTH,
            topics::BODY_VEL,
        ] {
            let q = for_topic(t);
            assert!(q.safe_overflow, "{t}");
            assert!(q.subscriber_max_buffer_size >= q.history_size, "{t}");
        }
    }
}
