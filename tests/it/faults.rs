//! Faults from outside (issue 9): slow clients, oversized headers, a full or read-only data
//! directory. Each test checks that the fault is contained (the offender is cut off or refused
//! with the documented status) and that everyone else is served.

use std::time::{Duration, Instant};

use serde_json::json;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use crate::common::{problem, Server};

/// What a raw connection saw: the bytes the server sent before closing, and when it closed
/// (`None` if it was still open when the test gave up).
struct Ended {
    response: String,
    after: Option<Duration>,
}

/// Writes `head` at once, then `trickle` one byte every `every`, until the server closes the
/// connection or `give_up` passes. Returns what the server sent.
async fn trickle(
    addr: std::net::SocketAddr,
    head: Vec<u8>,
    trickle: Vec<u8>,
    every: Duration,
    give_up: Duration,
) -> Ended {
    let t0 = Instant::now();
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(&head).await.unwrap();
    let (mut r, mut w) = s.into_split();
    let reader = tokio::spawn(async move {
        let mut got = Vec::new();
        let _ = r.read_to_end(&mut got).await;
        (String::from_utf8_lossy(&got).into_owned(), t0.elapsed())
    });
    let writer = async {
        for b in trickle.iter().cycle() {
            tokio::time::sleep(every).await;
            if w.write_all(&[*b]).await.is_err() {
                break;
            }
        }
    };
    tokio::select! {
        done = reader => {
            let (response, after) = done.unwrap();
            Ended { response, after: Some(after) }
        }
        () = writer => Ended { response: String::new(), after: None },
        () = tokio::time::sleep(give_up) => Ended { response: String::new(), after: None },
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_clients_are_cut_off_while_others_are_served() {
    let s = Server::start(|c| {
        c.header_read_timeout_secs = 2;
        c.body_read_timeout_secs = 2;
    })
    .await;
    let addr = s.addr;
    let give_up = Duration::from_secs(30);
    // Five clients that never finish their headers: a byte every 200 ms, so the connection is
    // never idle long enough for an idle timeout; only a total header deadline cuts them.
    let mut slow = Vec::new();
    for i in 0..5 {
        let head = format!("GET /healthz HTTP/1.1\r\nhost: x\r\nx-slow-{i}: ").into_bytes();
        slow.push(tokio::spawn(trickle(
            addr,
            head,
            b"a".to_vec(),
            Duration::from_millis(200),
            give_up,
        )));
    }
    // One client that sends its headers and trickles its body at 5 bytes/s (of 1000 announced).
    let body_head =
        b"POST /v1/assets HTTP/1.1\r\nhost: x\r\ncontent-type: application/octet-stream\r\n\
content-length: 1000\r\n\r\n"
            .to_vec();
    let body_slow = tokio::spawn(trickle(
        addr,
        body_head,
        b"x".to_vec(),
        Duration::from_millis(200),
        give_up,
    ));

    // Meanwhile a normal client is served, again and again, while the slow ones are connected.
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(10))
        .build()
        .unwrap();
    let mut served = 0;
    let mut slowest = Duration::ZERO;
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(1500) {
        let t = Instant::now();
        let r = client.get(s.url("/v1/jobs")).send().await.unwrap();
        assert_eq!(r.status().as_u16(), 200);
        slowest = slowest.max(t.elapsed());
        served += 1;
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let still_open = slow.iter().filter(|h| !h.is_finished()).count();
    assert_eq!(
        still_open, 5,
        "the normal client was served while every slow client was still connected"
    );
    assert!(served >= 5, "served {served}");
    eprintln!("normal client: {served} requests during the slow clients, slowest {slowest:?}");

    for h in slow {
        let e = h.await.unwrap();
        let after = e
            .after
            .expect("a slow-header client was never disconnected");
        // hyper closes without a response; never before the deadline.
        assert!(e.response.is_empty(), "{:?}", e.response);
        assert!(after >= Duration::from_secs(2), "{after:?}");
        eprintln!("slow headers: closed after {after:?}");
    }
    let e = body_slow.await.unwrap();
    let after = e
        .after
        .expect("the slow-body client was never disconnected");
    assert!(e.response.starts_with("HTTP/1.1 408"), "{:?}", e.response);
    assert!(e.response.contains("application/problem+json"));
    assert!(e.response.contains("request-timeout"));
    assert!(after >= Duration::from_secs(2), "{after:?}");
    eprintln!("slow body: 408 after {after:?}");

    // A body that pauses less than the idle timeout and flows fast enough is not cut.
    let r = client
        .post(s.url("/v1/assets"))
        .header("content-type", "application/octet-stream")
        .body(reqwest::Body::wrap_stream(futures_util::stream::iter(
            (0..3).map(|i| Ok::<_, std::io::Error>(vec![i as u8; 64 << 10])),
        )))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201, "{}", r.text().await.unwrap());
    let r = client.get(s.url("/healthz")).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);
}

/// Sends one raw request and returns the status line (empty if the server closed without one).
async fn raw_status(addr: std::net::SocketAddr, req: &[u8]) -> String {
    let mut s = TcpStream::connect(addr).await.unwrap();
    // The server may answer and close before it has read everything; a failed write is fine.
    let _ = s.write_all(req).await;
    let mut got = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut got)).await;
    String::from_utf8_lossy(&got)
        .lines()
        .next()
        .unwrap_or("")
        .to_string()
}

#[tokio::test]
async fn oversized_headers_get_431_and_the_server_stays_up() {
    let s = Server::start(|c| {
        c.max_header_count = 32;
        c.max_header_bytes = 4096;
    })
    .await;
    let req = |n: usize, value_len: usize| {
        let mut r = String::from("GET /healthz HTTP/1.1\r\nhost: x\r\nconnection: close\r\n");
        for i in 0..n {
            r.push_str(&format!("x-h{i}: {}\r\n", "v".repeat(value_len)));
        }
        r.push_str("\r\n");
        r.into_bytes()
    };
    // Under both limits: served.
    assert!(raw_status(s.addr, &req(20, 10)).await.contains(" 200 "));
    // Too many fields (40 + 2 > 32).
    let st = raw_status(s.addr, &req(40, 10)).await;
    assert!(st.contains(" 431 "), "too many headers: {st:?}");
    // Too many bytes: few fields, one of 8 KiB.
    let st = raw_status(s.addr, &req(1, 8 << 10)).await;
    assert!(st.contains(" 431 "), "headers too large: {st:?}");
    // A flood of header bytes far past the limit (1 MiB): refused the same way, nothing buffered.
    let st = raw_status(s.addr, &req(1, 1 << 20)).await;
    assert!(st.contains(" 431 "), "header flood: {st:?}");
    // Everyone else is still served.
    let r = s.client.get(s.url("/readyz")).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);
}

/// A tmpfs mounted on a temporary directory, unmounted when dropped.
struct Tmpfs {
    dir: tempfile::TempDir,
}

impl Tmpfs {
    fn mount(size: &str) -> Result<Tmpfs, String> {
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        run(
            "mount",
            &["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"],
            dir.path(),
        )?;
        Ok(Tmpfs { dir })
    }

    fn path(&self) -> &std::path::Path {
        self.dir.path()
    }

    fn remount(&self, mode: &str) {
        run("mount", &["-o", &format!("remount,{mode}")], self.path()).unwrap();
    }

    /// Writes zeros to `fill` until the file system is full.
    fn fill(&self) {
        use std::io::Write;
        let mut f = std::fs::File::create(self.path().join("fill")).unwrap();
        let chunk = vec![0u8; 64 << 10];
        while f.write_all(&chunk).is_ok() {}
        // Byte by byte into the last partial page.
        while f.write_all(&[0]).is_ok() {}
    }

    fn free(&self) {
        std::fs::remove_file(self.path().join("fill")).unwrap();
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = run("umount", &["-l"], self.path());
    }
}

fn run(cmd: &str, args: &[&str], dir: &std::path::Path) -> Result<(), String> {
    let out = std::process::Command::new(cmd)
        .args(args)
        .arg(dir)
        .output()
        .map_err(|e| format!("{cmd}: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "{cmd} {args:?} failed: {}",
            String::from_utf8_lossy(&out.stderr)
        ))
    }
}

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("Uid:"))
                .and_then(|l| l.split_whitespace().nth(2).map(|u| u == "0"))
        })
        .unwrap_or(false)
}

async fn assert_503(s: &Server, what: &str) {
    let r = s.client.get(s.url("/readyz")).send().await.unwrap();
    assert_eq!(r.headers()["retry-after"], "5", "{what}: readyz");
    problem(r, 503, "unavailable").await;
    let r = s.sleepy(json!({}), what.as_bytes()).await;
    assert_eq!(r.headers()["retry-after"], "5", "{what}: submit");
    problem(r, 503, "unavailable").await;
}

async fn assert_recovered(s: &Server, what: &str) {
    let r = s.client.get(s.url("/readyz")).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200, "{what}: readyz");
    let r = s
        .sleepy(json!({}), format!("after {what}").as_bytes())
        .await;
    let status = r.status().as_u16();
    let body = r.json::<serde_json::Value>().await.unwrap();
    assert_eq!(status, 202, "{what}: submit: {body}");
    let id = body["id"].as_str().unwrap().to_string();
    assert_eq!(s.wait_done(&id).await["status"], "succeeded", "{what}");
}

#[tokio::test]
async fn a_full_or_read_only_data_dir_answers_503_and_recovers() {
    if !is_root() {
        eprintln!(
            "SKIPPED a_full_or_read_only_data_dir_answers_503_and_recovers: not root, so it \
             cannot mount a tmpfs as the data directory (CI runs as root)"
        );
        return;
    }
    let _ = tracing_subscriber::fmt().with_test_writer().try_init();
    let fs = match Tmpfs::mount("4m") {
        Ok(fs) => fs,
        Err(e) => panic!("running as root but cannot mount a tmpfs: {e}"),
    };
    let data = fs.path().to_path_buf();
    let s = Server::start(move |c| c.data_dir = data).await;
    assert_recovered(&s, "start").await;

    // A job accepted while there is space, whose outputs cannot be written: the disk fills while
    // it runs. It ends `failed` with a storage error; it is neither lost nor stuck.
    let r = s
        .sleepy(
            json!({"stages": 1, "ms": 1500}),
            b"accepted before the disk filled",
        )
        .await;
    assert_eq!(r.status().as_u16(), 202);
    let id = r.json::<serde_json::Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    s.wait_running(&id).await;
    fs.fill();
    let done = s.wait_done(&id).await;
    assert_eq!(done["status"], "failed", "{done}");
    assert_eq!(
        done["error"]["type"], "https://phenomena.dev/problems/storage",
        "{done}"
    );
    assert!(
        done["error"]["detail"]
            .as_str()
            .unwrap()
            .contains("full or read-only"),
        "{done}"
    );

    assert_503(&s, "disk full").await;
    // The server is up and still answers what needs no writing.
    assert_eq!(s.job(&id).await["status"], "failed");
    let r = s.client.get(s.url("/healthz")).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);

    fs.free();
    assert_recovered(&s, "disk full").await;
    // The failed request can be submitted again and now succeeds.
    let r = s
        .sleepy(
            json!({"stages": 1, "ms": 1500}),
            b"accepted before the disk filled",
        )
        .await;
    assert_eq!(r.status().as_u16(), 202);
    let again = r.json::<serde_json::Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    assert_ne!(again, id);
    assert_eq!(s.wait_done(&again).await["status"], "succeeded");

    fs.remount("ro");
    assert_503(&s, "read-only").await;
    fs.remount("rw");
    assert_recovered(&s, "read-only").await;
    drop(s);
}
