//! Datagrams to the receiver without ever waiting on it.
//!
//! The socket is non-blocking and connected to the receiver's address, so a full send buffer
//! (`WouldBlock`) and a receiver that is not listening (the ICMP port-unreachable the kernel
//! reports on a connected UDP socket as `ConnectionRefused`, on a later send) come back as errors
//! at once. Every error is counted, the first of each kind is logged, and the frame's bundle is
//! dropped: a stalled or absent avatar app must never hold up the graph. A receiver that starts
//! (again) later gets the frames from then on.

use std::io::ErrorKind;
use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};

use anyhow::Context;

/// The counts a [`Sender`] keeps.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SendCounts {
    /// Datagrams the kernel took.
    pub sent: u64,
    /// Datagrams dropped because a send failed.
    pub failed: u64,
}

/// A non-blocking UDP sender to one receiver.
#[derive(Debug)]
pub struct Sender {
    socket: UdpSocket,
    target: SocketAddr,
    /// Whether `connect` worked (send) or not (send_to, e.g. no route yet).
    connected: bool,
    counts: SendCounts,
    logged: Vec<ErrorKind>,
    /// Who to name in the log.
    stage: String,
}

impl Sender {
    /// A sender to `host:port`. Resolving the host is the only thing that can fail: a name that
    /// does not resolve is a configuration error, named with the parameters it came from.
    pub fn new(stage: &str, host: &str, port: u16) -> anyhow::Result<Sender> {
        let target = resolve(host, port)
            .with_context(|| format!("stage {stage}: params.host {host:?}, params.port {port}"))?;
        let local: SocketAddr = if target.is_ipv4() {
            ([0, 0, 0, 0], 0).into()
        } else {
            (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
        };
        let socket = UdpSocket::bind(local)
            .and_then(|s| s.set_nonblocking(true).map(|()| s))
            .with_context(|| format!("stage {stage}: cannot open a UDP socket"))?;
        let mut sender = Sender {
            socket,
            target,
            connected: false,
            counts: SendCounts::default(),
            logged: Vec::new(),
            stage: stage.to_owned(),
        };
        match sender.socket.connect(target) {
            Ok(()) => sender.connected = true,
            // No route now (a network not up yet): each send says so and is counted.
            Err(e) => sender.log_once(&e),
        }
        Ok(sender)
    }

    /// The receiver's address.
    pub fn target(&self) -> SocketAddr {
        self.target
    }

    /// What was sent and dropped so far.
    pub fn counts(&self) -> SendCounts {
        self.counts
    }

    /// Sends one datagram; returns whether it went out. Never waits, never fails the stage.
    pub fn send(&mut self, datagram: &[u8]) -> bool {
        let result = if self.connected {
            self.socket.send(datagram)
        } else {
            self.socket.send_to(datagram, self.target)
        };
        match result {
            Ok(n) if n == datagram.len() => {
                self.counts.sent += 1;
                true
            }
            Ok(n) => {
                let short =
                    std::io::Error::other(format!("only {n} of {} bytes sent", datagram.len()));
                self.fail(&short)
            }
            Err(e) => self.fail(&e),
        }
    }

    fn fail(&mut self, e: &std::io::Error) -> bool {
        self.counts.failed += 1;
        self.log_once(e);
        false
    }

    fn log_once(&mut self, e: &std::io::Error) {
        if self.logged.contains(&e.kind()) {
            return;
        }
        self.logged.push(e.kind());
        let why = match e.kind() {
            ErrorKind::ConnectionRefused => " (nothing listens there: is the receiver running?)",
            ErrorKind::WouldBlock => " (the socket's send buffer is full)",
            _ => "",
        };
        tracing::warn!(
            stage = self.stage,
            "cannot send to {}: {e}{why}; from now on such failures are only counted (see the summary)",
            self.target
        );
    }
}

fn resolve(host: &str, port: u16) -> anyhow::Result<SocketAddr> {
    (host, port)
        .to_socket_addrs()
        .with_context(|| format!("cannot resolve {host:?}"))?
        .next()
        .with_context(|| format!("{host:?} resolves to no address"))
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use super::*;

    fn listener() -> UdpSocket {
        let s = UdpSocket::bind("127.0.0.1:0").unwrap();
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        s
    }

    #[test]
    fn datagrams_arrive_whole() {
        let rx = listener();
        let port = rx.local_addr().unwrap().port();
        let mut tx = Sender::new("vmc", "127.0.0.1", port).unwrap();
        let payload: Vec<u8> = (0..1900u32).map(|i| (i % 251) as u8).collect();
        assert!(tx.send(&payload));
        let mut buf = [0u8; 4096];
        let n = rx.recv(&mut buf).unwrap();
        assert_eq!(&buf[..n], &payload[..]);
        assert_eq!(tx.counts(), SendCounts { sent: 1, failed: 0 });
    }

    #[test]
    fn a_receiver_that_is_not_listening_is_counted_never_waited_on() {
        // A port that was free a moment ago: nothing listens, the kernel answers each datagram
        // with port-unreachable, which the next send on the connected socket reports.
        let port = listener().local_addr().unwrap().port();
        let mut tx = Sender::new("vmc", "127.0.0.1", port).unwrap();
        let started = Instant::now();
        for _ in 0..200 {
            tx.send(&[0u8; 1900]);
        }
        let c = tx.counts();
        assert_eq!(c.sent + c.failed, 200);
        assert!(c.failed >= 50, "{c:?}");
        assert!(
            started.elapsed() < Duration::from_secs(1),
            "{:?}",
            started.elapsed()
        );
    }

    #[test]
    fn an_unknown_host_is_an_error_naming_the_parameters() {
        let err = Sender::new("vmc", "no such host.invalid", 39539).unwrap_err();
        let text = format!("{err:#}");
        assert!(
            text.contains("stage vmc: params.host \"no such host.invalid\", params.port 39539"),
            "{text}"
        );
    }

    #[test]
    fn ipv6_loopback_works_too() {
        let Ok(rx) = UdpSocket::bind("[::1]:0") else {
            return; // no IPv6 on this machine
        };
        rx.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut tx = Sender::new("vmc", "::1", rx.local_addr().unwrap().port()).unwrap();
        assert!(tx.send(b"hello"));
        let mut buf = [0u8; 16];
        assert_eq!(rx.recv(&mut buf).unwrap(), 5);
    }
}
