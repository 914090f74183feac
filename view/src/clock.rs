//! The scene's clock as the viewers play it: one clip time, in `[0, span]`, advanced here (the
//! view is what asks the cluster for each frame's time), at a speed, looping or stopping at the
//! end. Every frame request carries the clock's time and every frame header the time it was
//! rendered at, so the page shows the clip time of the frame on screen (`docs/live-view.md`).

use crate::camera::SteerError;
use std::time::{Duration, Instant};

/// Playback speeds a viewer may set (multiples of real time).
pub const MIN_SPEED: f32 = 0.25;
pub const MAX_SPEED: f32 = 4.0;
/// Scene times a viewer may seek to, seconds either side of 0 (mapped into the clip).
pub(crate) const MAX_SEEK: f32 = 1e6;

/// Clip time when paused, and while playing the instant it was at it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clock {
    /// Clip time (seconds) when paused, or at `since` while playing.
    pub time: f32,
    pub since: Option<Instant>,
    /// The animation's span (seconds: the longest period in it, what the page's slider spans);
    /// 0 for a still scene.
    pub span: f32,
    /// At the end of the span: start over (else stop there).
    pub looping: bool,
    /// Clip seconds per second.
    pub speed: f32,
}

/// Scene time `t` as a time in the clip `[0, span]`: wrapped when looping, clamped otherwise
/// (0 for a still scene or a time that is not finite). A clock that ran 12.15 s over a 3.42 s
/// clip is at 1.89 s.
pub fn clip_time(t: f32, span: f32, looping: bool) -> f32 {
    if !t.is_finite() || !span.is_finite() || span <= 0.0 {
        return 0.0;
    }
    if looping {
        // `rem_euclid` of a value just below a multiple of `span` can round to `span` itself.
        let w = t.rem_euclid(span);
        if w >= span { 0.0 } else { w }
    } else {
        t.clamp(0.0, span)
    }
}

impl Clock {
    /// A paused clock at 0 over `span` seconds (0: a still scene), looping at normal speed.
    pub fn new(span: f32) -> Clock {
        Clock {
            time: 0.0,
            since: None,
            span: if span.is_finite() { span.max(0.0) } else { 0.0 },
            looping: true,
            speed: 1.0,
        }
    }

    /// Scene time `elapsed` after `since`, before it is mapped into the clip.
    fn raw(&self, elapsed: Duration) -> f32 {
        match self.since {
            None => self.time,
            Some(_) => self.time + elapsed.as_secs_f32() * self.speed,
        }
    }

    fn elapsed(&self) -> Duration {
        self.since.map_or(Duration::ZERO, |s| s.elapsed())
    }

    /// The clip time `elapsed` after `since` (the paused time when paused).
    pub fn at(&self, elapsed: Duration) -> f32 {
        clip_time(self.raw(elapsed), self.span, self.looping)
    }

    /// The clip time now: what the next frame requested is posed at.
    pub fn now(&self) -> f32 {
        self.at(self.elapsed())
    }

    /// Whether the clock runs: started, and not stopped at the end of a clip that does not loop.
    pub fn playing(&self) -> bool {
        self.since.is_some() && !self.ended(self.elapsed())
    }

    fn ended(&self, elapsed: Duration) -> bool {
        !self.looping && self.raw(elapsed) >= self.span
    }

    /// Whether the scene moves at all (otherwise frames carry no time).
    pub fn animated(&self) -> bool {
        self.span > 0.0
    }

    /// Restarts the clock's count from the time it shows now (before a change of speed or loop).
    fn rebase(&mut self) {
        self.time = self.now();
        if self.since.is_some() {
            self.since = Some(Instant::now());
        }
    }

    /// Starts or stops the clock (no-op for a still scene, or when already so). Playing a clip
    /// that stopped at its end starts it over.
    pub fn play(&mut self, on: bool) {
        if !self.animated() || on == self.playing() {
            return;
        }
        if on {
            if self.ended(self.elapsed()) {
                self.time = 0.0;
            }
            self.since = Some(Instant::now());
        } else {
            self.time = self.now();
            self.since = None;
        }
    }

    /// Jumps to scene time `t`, mapped into the clip (playing on from there if playing).
    pub fn seek(&mut self, t: f32) -> Result<(), SteerError> {
        if !t.is_finite() {
            return Err(SteerError::NotFinite("scene time"));
        }
        if t.abs() > MAX_SEEK {
            return Err(SteerError::OutOfRange(format!(
                "scene time {t} s is beyond ±10⁶ s"
            )));
        }
        self.time = clip_time(t, self.span, self.looping);
        if self.since.is_some() {
            self.since = Some(Instant::now());
        }
        Ok(())
    }

    /// Sets the playback speed (`MIN_SPEED` to `MAX_SPEED` times real time).
    pub fn set_speed(&mut self, speed: f32) -> Result<(), SteerError> {
        if !speed.is_finite() {
            return Err(SteerError::NotFinite("playback speed"));
        }
        if !(MIN_SPEED..=MAX_SPEED).contains(&speed) {
            return Err(SteerError::OutOfRange(format!(
                "a playback speed is between {MIN_SPEED}× and {MAX_SPEED}×, not {speed}×"
            )));
        }
        self.rebase();
        self.speed = speed;
        Ok(())
    }

    /// Loops at the end of the span, or stops there.
    pub fn set_looping(&mut self, on: bool) {
        if on != self.looping {
            self.rebase();
            self.looping = on;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() < 1e-4
    }

    #[test]
    fn the_clock_shows_the_clip_time_and_wraps() {
        // The page once showed 12.15 s on its label beside 1.9 s on its slider for a 3.42 s
        // clip: the unwrapped scene time and the clip time. The clock has one: the clip's.
        let mut c = Clock::new(3.42);
        c.since = Some(Instant::now());
        let t = c.at(Duration::from_secs_f32(12.15));
        assert!(close(t, 12.15 - 3.0 * 3.42), "{t}");
        assert!((0.0..3.42).contains(&t));
        // Negative control: without wrapping the same run is past the clip's end.
        assert!(c.raw(Duration::from_secs_f32(12.15)) > c.span);
        // Every time a looping clock shows lies in the clip.
        for ms in (0..20_000).step_by(37) {
            let t = c.at(Duration::from_millis(ms));
            assert!((0.0..3.42).contains(&t), "{ms} ms: {t}");
        }
        // Seeks map into the clip too, forwards and backwards.
        c.seek(-1.0).unwrap();
        assert!(close(c.time, 2.42), "{}", c.time);
        c.seek(7.0).unwrap();
        assert!(close(c.time, 7.0 - 6.84), "{}", c.time);
        assert!(clip_time(f32::NAN, 3.42, true) == 0.0);
        assert!(
            clip_time(5.0, 0.0, true) == 0.0,
            "a still scene has no time"
        );
    }

    #[test]
    fn speed_scales_the_clock_and_a_clip_that_does_not_loop_stops_at_its_end() {
        let mut c = Clock::new(4.0);
        c.set_speed(2.0).unwrap();
        c.since = Some(Instant::now());
        assert!(close(c.at(Duration::from_secs(1)), 2.0));
        assert!(close(c.at(Duration::from_secs(3)), 2.0), "wrapped at 4 s");
        c.set_speed(0.25).unwrap();
        c.time = 0.0;
        assert!(close(c.at(Duration::from_secs(2)), 0.5));
        for bad in [0.0, 0.1, 5.0, -1.0] {
            assert!(c.set_speed(bad).is_err(), "{bad}×");
        }
        assert!(matches!(
            c.set_speed(f32::NAN),
            Err(SteerError::NotFinite(_))
        ));
        assert!(close(c.speed, 0.25), "a refused speed changes nothing");

        let mut once = Clock::new(4.0);
        once.set_looping(false);
        once.time = 3.5;
        once.since = Some(Instant::now());
        assert!(
            close(once.at(Duration::from_secs(10)), 4.0),
            "held at the end"
        );
        // A clip played past its end has stopped; playing it again starts it over.
        once.since = Instant::now().checked_sub(Duration::from_secs(1));
        assert!(once.since.is_some());
        assert!(!once.playing());
        once.play(true);
        assert!(once.playing() && once.now() < 0.5, "{}", once.now());
    }

    #[test]
    fn a_still_scene_does_not_play() {
        let mut c = Clock::new(0.0);
        c.play(true);
        assert!(!c.playing() && !c.animated());
        assert_eq!(c.now(), 0.0);
    }
}
