//! The joint_states stream: one JointState per LOCATION sample, stamped when the sample
//! reached the bridge, and never behind: when a publish waits (the reliable writer's send
//! window is full of samples a slow reader has not acknowledged: up to 100 ms a write, by
//! ros2-client's default), the samples that queued meanwhile are skipped for the newest.
//! Publishing them in order instead kept the stream up to `SAMPLE_QUEUE` samples (1.3 s
//! at 50 Hz) late, and a JointState of before a stop could reach a client after the
//! CANCELED result (issue 30). A stale joint state is worse than a missing one.

use std::future::Future;

use super::Sample;

/// Publishes the samples from `samples` with `publish` until the channel closes: each
/// time the newest one queued. Returns how many were skipped.
pub(super) async fn publish_samples<F, Fut>(
    samples: &async_channel::Receiver<Sample>,
    mut publish: F,
) -> u64
where
    F: FnMut(Sample) -> Fut,
    Fut: Future<Output = ()>,
{
    let mut skipped = 0u64;
    while let Ok(mut sample) = samples.recv().await {
        let mut stale = 0;
        while let Ok(newer) = samples.try_recv() {
            sample = newer;
            stale += 1;
        }
        if stale > 0 {
            log::debug!("joint_states: {stale} stale samples skipped (the last publish waited)");
            skipped += stale;
        }
        publish(sample).await;
    }
    skipped
}

#[cfg(test)]
mod tests {
    use std::cell::RefCell;
    use std::time::SystemTime;

    use armctl::protocol::Location;

    use super::*;

    fn sample(k: i32) -> Sample {
        let mut location = Location::default();
        location.position[0] = k;
        Sample {
            location,
            stamp: SystemTime::UNIX_EPOCH + std::time::Duration::from_millis(20 * k as u64),
        }
    }

    /// Regression (issue 30): a publish that waits (the reliable writer's window full of
    /// samples a slow reader has not acknowledged) while more LOCATION samples queue must
    /// be followed by the newest sample, not by the oldest queued one: in rclpy.sh on Jazzy
    /// the JointStates after a CANCELED result still showed the arm moving, samples of
    /// before the stop published up to 0.4 s late. No clock: the first publish itself
    /// queues the samples that "came while it waited".
    #[test]
    fn after_a_slow_publish_the_newest_sample_is_next() {
        let (tx, rx) = async_channel::bounded(64);
        tx.try_send(sample(0)).unwrap();
        let published = RefCell::new(Vec::new());
        let skipped = async_io::block_on(publish_samples(&rx, |s: Sample| {
            let k = s.location.position[0];
            published.borrow_mut().push(k);
            if k == 0 {
                for later in 1..=10 {
                    tx.try_send(sample(later)).unwrap();
                }
            }
            if k == 10 {
                rx.close();
            }
            async {}
        }));
        assert_eq!(published.into_inner(), [0, 10]);
        assert_eq!(skipped, 9);
    }

    /// A publisher that keeps up (each sample published before the next comes) publishes
    /// every sample, in order.
    #[test]
    fn a_publisher_that_keeps_up_publishes_every_sample() {
        let (tx, rx) = async_channel::bounded(64);
        tx.try_send(sample(0)).unwrap();
        let published = RefCell::new(Vec::new());
        let skipped = async_io::block_on(publish_samples(&rx, |s: Sample| {
            let k = s.location.position[0];
            published.borrow_mut().push(k);
            if k < 4 {
                tx.try_send(sample(k + 1)).unwrap();
            } else {
                rx.close();
            }
            async {}
        }));
        assert_eq!(published.into_inner(), [0, 1, 2, 3, 4]);
        assert_eq!(skipped, 0);
    }
}
