//! Who may see what (`docs/live-view.md` § Access): a viewer on loopback, or one that presented
//! the token, sees and steers everything; one beyond loopback without it sees nothing but the page
//! unless the view was started with `public_watch`, when it watches with daemon addresses removed
//! from every text it is sent (`redact`).

use serde_json::Value;
use std::net::{IpAddr, SocketAddr};

/// What a viewer is allowed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Access {
    /// Sees everything and steers (loopback, or the token presented).
    Steer,
    /// Sees frames and the status with addresses removed (`public_watch`, no token).
    Watch,
    /// Sees nothing until it presents the token.
    Locked,
}

impl Access {
    pub(crate) fn can_steer(self) -> bool {
        self == Access::Steer
    }
    pub(crate) fn can_watch(self) -> bool {
        self != Access::Locked
    }
}

/// Whether `peer` is on loopback (an IPv4 loopback address mapped into IPv6 too).
pub(crate) fn on_loopback(peer: SocketAddr) -> bool {
    peer.ip().to_canonical().is_loopback()
}

/// What replaces an address in what a viewer without the token is sent.
pub(crate) const HIDDEN: &str = "[address]";

/// The addresses the view knows of (the daemons', the sink's): removed wherever they appear in
/// text a viewer without the token is sent, with anything else that looks like an address.
#[derive(Debug, Default, Clone)]
pub(crate) struct Addresses(Vec<String>);

impl Addresses {
    pub(crate) fn new<'a>(addresses: impl IntoIterator<Item = &'a str>) -> Addresses {
        let mut all: Vec<String> = Vec::new();
        for a in addresses {
            if a.is_empty() {
                continue;
            }
            all.push(a.to_string());
            // The host alone (a log line may name it without the port), where it cannot be
            // mistaken for a word: an IP address or a dotted name.
            if let Some((host, port)) = a.rsplit_once(':')
                && port.bytes().all(|b| b.is_ascii_digit())
            {
                let host = host.trim_start_matches('[').trim_end_matches(']');
                if host.parse::<IpAddr>().is_ok() || host.contains('.') {
                    all.push(host.to_string());
                }
            }
        }
        // Longest first, so an address goes whole before its host.
        all.sort_by_key(|a| std::cmp::Reverse(a.len()));
        all.dedup();
        Addresses(all)
    }

    /// `text` with every address in it replaced by `HIDDEN`.
    pub(crate) fn scrub(&self, text: &str) -> String {
        let mut out = text.to_string();
        for a in &self.0 {
            if out.contains(a.as_str()) {
                out = out.replace(a.as_str(), HIDDEN);
            }
        }
        scrub_patterns(&out)
    }

    /// Removes addresses from a JSON message: the plan's sink address, and every address in its
    /// strings.
    pub(crate) fn redact(&self, v: &mut Value) {
        if let Some(plan) = v.get_mut("plan").and_then(Value::as_object_mut) {
            plan.insert("sink".into(), Value::Null);
        }
        self.redact_strings(v);
    }

    fn redact_strings(&self, v: &mut Value) {
        match v {
            Value::String(s) => {
                let clean = self.scrub(s);
                if clean != *s {
                    *s = clean;
                }
            }
            Value::Array(a) => a.iter_mut().for_each(|x| self.redact_strings(x)),
            Value::Object(o) => o.values_mut().for_each(|x| self.redact_strings(x)),
            _ => {}
        }
    }
}

/// Replaces what looks like an address in `text`: an IP address, `IP:port`, `[IPv6]:port` or
/// `host:port`.
fn scrub_patterns(text: &str) -> String {
    let word = |c: char| c.is_ascii_alphanumeric() || ".:-_[]%".contains(c);
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(start) = rest.find(word) {
        out.push_str(&rest[..start]);
        let run = &rest[start..];
        let len = run.find(|c: char| !word(c)).unwrap_or(run.len());
        let w = &run[..len];
        // Trailing punctuation belongs to the sentence ("lost: 10.0.0.5:7000.").
        let core = w.trim_end_matches(['.', ':', '-', '_']);
        if looks_like_address(core) {
            out.push_str(HIDDEN);
            out.push_str(&w[core.len()..]);
        } else {
            out.push_str(w);
        }
        rest = &run[len..];
    }
    out.push_str(rest);
    out
}

fn looks_like_address(w: &str) -> bool {
    if w.parse::<SocketAddr>().is_ok() {
        return true;
    }
    let bare = w.trim_start_matches('[').trim_end_matches(']');
    // IPv4 needs four parts; IPv6 needs a "::" or eight groups, so "Illum:Rgb16F" is no address.
    if bare.parse::<IpAddr>().is_ok() {
        return true;
    }
    // host:port
    match w.rsplit_once(':') {
        Some((host, port)) => {
            !host.is_empty()
                && !port.is_empty()
                && port.len() <= 5
                && port.bytes().all(|b| b.is_ascii_digit())
                && host
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'.' || b == b'-' || b == b'_')
                && host.bytes().any(|b| b.is_ascii_alphabetic() || b == b'.')
        }
        None => false,
    }
}

/// Whether two digests are equal, looking at every byte whatever the first difference.
pub(crate) fn same_digest(a: &[u8; 32], b: &[u8; 32]) -> bool {
    use subtle::ConstantTimeEq;
    a.ct_eq(b).into()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn addresses_are_removed_and_ids_kept() {
        let a = Addresses::new([
            "10.1.2.3:7401",
            "render-7.lab.example:7402",
            "sink-host:9000",
        ]);
        let text = "node-3 lost: connection to 10.1.2.3:7401 reset; render-7.lab.example \
                    refused; 192.168.4.4 down, [fe80::1]:80 and comp-1:7000. Illum:Rgb16F ok";
        let got = a.scrub(text);
        assert_eq!(
            got,
            "node-3 lost: connection to [address] reset; [address] refused; [address] down, \
             [address] and [address]. Illum:Rgb16F ok"
        );
        // Negative control: nothing that is no address changes.
        let plain = "frame 12 waited 300 ms on node-3 (lost: timeout), epoch 5 f16x6";
        assert_eq!(a.scrub(plain), plain);
        let mut status = json!({"type": "status", "plan": {"sink": "127.0.0.1:9000",
            "nodes": [{"id": "node-0"}]}, "lost": [{"id": "node-1",
            "reason": "refused by 10.1.2.3:7401"}]});
        a.redact(&mut status);
        assert_eq!(status["plan"]["sink"], Value::Null);
        assert_eq!(status["plan"]["nodes"][0]["id"], "node-0");
        assert_eq!(status["lost"][0]["reason"], "refused by [address]");
    }

    #[test]
    fn digests_compare_whole() {
        let a = [7u8; 32];
        let mut b = a;
        assert!(same_digest(&a, &b));
        b[31] ^= 1;
        assert!(!same_digest(&a, &b));
        b = a;
        b[0] ^= 0x80;
        assert!(!same_digest(&a, &b));
    }
}
