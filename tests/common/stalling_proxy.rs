//! A loopback TCP proxy that stops passing a client's bytes on after a set amount: a
//! network that stalls mid-upload. Tests that must interrupt a put half-way (a killed
//! writer, a dying server) put it between the store and the server, so the put is
//! certain to be half-way when they act, however fast the machine is — polling a fast
//! loopback upload for its middle can miss it.
//!
//! Bytes from the server to the client always pass. Connections made after the stall
//! stall at once (their first byte would pass the limit).
#![allow(dead_code)]

use std::io::{Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

pub struct StallingProxy {
    /// The loopback port clients connect to instead of the server's.
    pub port: u16,
    stop: Arc<AtomicBool>,
    /// Every socket the proxy holds, to be shut when it stops (which ends their threads).
    sockets: Arc<Mutex<Vec<TcpStream>>>,
    acceptor: Option<JoinHandle<()>>,
}

impl StallingProxy {
    /// Forwards connections to `127.0.0.1:target`, passing at most `pass_bytes` bytes from
    /// clients to the server in all connections together.
    pub fn start(target: u16, pass_bytes: u64) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").expect("a loopback port for the proxy");
        let port = listener.local_addr().expect("the proxy's address").port();
        listener.set_nonblocking(true).expect("non-blocking accept");
        let stop = Arc::new(AtomicBool::new(false));
        let sockets = Arc::new(Mutex::new(Vec::new()));
        let passed = Arc::new(AtomicU64::new(0));
        let acceptor = {
            let (stop, sockets) = (stop.clone(), sockets.clone());
            std::thread::spawn(move || {
                while !stop.load(Ordering::SeqCst) {
                    match listener.accept() {
                        Ok((client, _)) => {
                            let Ok(server) = TcpStream::connect(("127.0.0.1", target)) else {
                                let _ = client.shutdown(Shutdown::Both);
                                continue;
                            };
                            client.set_nonblocking(false).expect("blocking client socket");
                            connect_pair(client, server, pass_bytes, &passed, &stop, &sockets);
                        }
                        Err(_) => std::thread::sleep(Duration::from_millis(2)),
                    }
                }
            })
        };
        Self { port, stop, sockets, acceptor: Some(acceptor) }
    }

    /// Stops the proxy: every connection through it is shut (clients see it reset).
    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        for s in self.sockets.lock().unwrap().drain(..) {
            let _ = s.shutdown(Shutdown::Both);
        }
        if let Some(a) = self.acceptor.take() {
            let _ = a.join();
        }
    }
}

impl Drop for StallingProxy {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Two threads for one connection: server to client freely, client to server up to the
/// shared byte allowance, then holding (reading nothing more, so the client's sends back
/// up and block) until the proxy stops.
fn connect_pair(client: TcpStream, server: TcpStream, pass_bytes: u64, passed: &Arc<AtomicU64>, stop: &Arc<AtomicBool>, sockets: &Arc<Mutex<Vec<TcpStream>>>) {
    let clones = || (client.try_clone().expect("client socket"), server.try_clone().expect("server socket"));
    {
        let mut held = sockets.lock().unwrap();
        let (c, s) = clones();
        held.push(c);
        held.push(s);
    }
    let (mut c_read, mut s_write) = clones();
    let (passed, stop) = (passed.clone(), stop.clone());
    std::thread::spawn(move || {
        let mut buf = vec![0u8; 64 << 10];
        while let Ok(n) = c_read.read(&mut buf) {
            if n == 0 {
                let _ = s_write.shutdown(Shutdown::Write);
                return;
            }
            let before = passed.fetch_add(n as u64, Ordering::SeqCst);
            let allowed = pass_bytes.saturating_sub(before).min(n as u64) as usize;
            if s_write.write_all(&buf[..allowed]).is_err() {
                break;
            }
            if allowed < n {
                while !stop.load(Ordering::SeqCst) {
                    std::thread::sleep(Duration::from_millis(10));
                }
                break;
            }
        }
        let _ = s_write.shutdown(Shutdown::Both);
    });
    let (mut s_read, mut c_write) = (server, client);
    std::thread::spawn(move || {
        let _ = std::io::copy(&mut s_read, &mut c_write);
        let _ = c_write.shutdown(Shutdown::Write);
    });
}
