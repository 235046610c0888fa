//! `fpc-sim view`, the bench console: a page served on 127.0.0.1 that shows the machine
//! live — position and reference, both sections' forces, both chamber pressures, the
//! rotation angle, the mode, faults, the scope's window when it fires — and whose controls
//! send the link's commands ([`feed`]).
//!
//! The server is axum on a one-thread tokio runtime: the page, its script and the chart
//! library (uPlot 1.6.32 from npm, MIT, its licence at `/licenses/uPlot.txt`) are compiled
//! into the binary, so nothing is fetched at run time; the live data and the controls go
//! over one WebSocket (`/ws`, [`protocol`]). The link itself runs on its own thread: the
//! simulated board is stepped there in real time, whatever the pages do.

pub mod feed;
pub mod protocol;

use std::future::IntoFuture;
use std::net::{Ipv4Addr, SocketAddr};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use axum::extract::ws::{Message as WsMessage, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::http::header::CONTENT_TYPE;
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use tokio::sync::broadcast;

use crate::failure::Failure;
use feed::{Feed, Source};
use protocol::{Control, Message};

const INDEX: &str = include_str!("page/index.html");
const CONSOLE_JS: &str = include_str!("page/console.js");
const CONSOLE_CSS: &str = include_str!("page/console.css");
const UPLOT_JS: &str = include_str!("page/uPlot.iife.min.js");
const UPLOT_CSS: &str = include_str!("page/uPlot.min.css");
const UPLOT_LICENSE: &str = include_str!("page/uPlot.LICENSE");

/// What `fpc-sim view` serves.
pub struct ViewOptions {
    /// Where the stream comes from.
    pub source: Source,
    /// Port on 127.0.0.1; 0 = any free port.
    pub port: u16,
    /// Where recordings go (`DIR/rec-N/`).
    pub out: std::path::PathBuf,
    /// End after this long (`None`: at Ctrl-C).
    pub seconds: Option<f64>,
    /// The tool's version, shown on the page.
    pub version: &'static str,
}

/// What every page connection shares.
struct Shared {
    messages: broadcast::Sender<Arc<str>>,
    controls: mpsc::Sender<Control>,
    hello: String,
}

/// Serves the console until Ctrl-C (or `seconds`), telling `ready` the address first.
/// The link's failure (a recording that cannot be read, a probe that is gone) ends it.
pub fn serve(
    opts: ViewOptions,
    ready: impl FnOnce(SocketAddr, &str) -> Result<(), Failure>,
) -> Result<(), Failure> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::runtime(format!("cannot start the server: {e}")))?;
    let hello = serde_json::to_string(&Message::Hello {
        mode: opts.source.mode().to_string(),
        source: opts.source.describe(),
        version: opts.version.to_string(),
    })
    .map_err(|e| Failure::runtime(e.to_string()))?;
    let describe = opts.source.describe();
    let listener = runtime.block_on(async {
        tokio::net::TcpListener::bind((Ipv4Addr::LOCALHOST, opts.port))
            .await
            .map_err(|e| {
                Failure::bad_input(format!(
                    "--port {}: cannot listen on 127.0.0.1:{} ({e}); --port 0 takes any free port",
                    opts.port, opts.port
                ))
            })
    })?;
    let addr = listener
        .local_addr()
        .map_err(|e| Failure::runtime(format!("cannot read the server's address: {e}")))?;
    let feed = Feed::start(opts.source, opts.out);
    let shared = Arc::new(Shared {
        messages: feed.messages.clone(),
        controls: feed.controls.clone(),
        hello,
    });
    let app = Router::new()
        .route("/", get(|| async { Html(INDEX) }))
        .route(
            "/console.js",
            get(|| async { asset("text/javascript", CONSOLE_JS) }),
        )
        .route(
            "/console.css",
            get(|| async { asset("text/css", CONSOLE_CSS) }),
        )
        .route(
            "/uPlot.js",
            get(|| async { asset("text/javascript", UPLOT_JS) }),
        )
        .route("/uPlot.css", get(|| async { asset("text/css", UPLOT_CSS) }))
        .route(
            "/licenses/uPlot.txt",
            get(|| async { asset("text/plain; charset=utf-8", UPLOT_LICENSE) }),
        )
        .route("/ws", get(socket))
        .with_state(shared);
    ready(addr, &describe)?;
    let started = Instant::now();
    let deadline = opts.seconds.map(Duration::from_secs_f64);
    let ends = async {
        loop {
            if crate::interrupt::interrupted()
                || feed.ended()
                || deadline.is_some_and(|d| started.elapsed() >= d)
            {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    };
    let served = runtime.block_on(async {
        tokio::select! {
            r = axum::serve(listener, app).into_future() => {
                r.map_err(|e| Failure::runtime(format!("the server failed: {e}")))
            }
            () = ends => Ok(()),
        }
    });
    // The pages' connections end with the runtime; the link ends after them, writing a
    // recording in progress.
    drop(runtime);
    let linked = feed.finish().map_err(Failure::runtime);
    served.and(linked)
}

/// A compiled-in file with its type.
fn asset(content_type: &'static str, body: &'static str) -> Response {
    ([(CONTENT_TYPE, content_type)], body).into_response()
}

async fn socket(ws: WebSocketUpgrade, State(shared): State<Arc<Shared>>) -> Response {
    ws.on_upgrade(move |s| session(s, shared))
}

/// One page: every message of the feed to it, its controls to the feed.
async fn session(mut socket: WebSocket, shared: Arc<Shared>) {
    let mut messages = shared.messages.subscribe();
    if socket
        .send(WsMessage::Text(shared.hello.clone().into()))
        .await
        .is_err()
    {
        return;
    }
    loop {
        tokio::select! {
            m = messages.recv() => {
                let text: String = match m {
                    Ok(text) => text.to_string(),
                    Err(broadcast::error::RecvError::Lagged(n)) => {
                        let m = Message::Log {
                            text: format!("this page fell behind: {n} batches of frames were not shown"),
                            level: "refused".into(),
                        };
                        serde_json::to_string(&m).unwrap_or_default()
                    }
                    Err(broadcast::error::RecvError::Closed) => break,
                };
                if socket.send(WsMessage::Text(text.into())).await.is_err() {
                    break;
                }
            }
            m = socket.recv() => match m {
                Some(Ok(WsMessage::Text(text))) => {
                    match serde_json::from_str::<Control>(text.as_str()) {
                        Ok(control) => {
                            if shared.controls.send(control).is_err() {
                                break;
                            }
                        }
                        Err(e) => {
                            let m = Message::Log {
                                text: format!("not a control of this console: {e}"),
                                level: "refused".into(),
                            };
                            let text = serde_json::to_string(&m).unwrap_or_default();
                            if socket.send(WsMessage::Text(text.into())).await.is_err() {
                                break;
                            }
                        }
                    }
                }
                Some(Ok(_)) => {}
                Some(Err(_)) | None => break,
            },
        }
    }
}
