"""The web viewer's page with a start time: ``testbed view RUN --web --at SECONDS``.

rerun's own web server (``rerun --serve-web``, on an internal port) serves the viewer's files; this server,
on the port the user opens, passes every request through to it and adds one script to the page: once the
viewer runs (``window._handle``), it sends the viewer-control request of
:func:`testbed.recording.timecursor.set_time_request` to the page's viewer, again until the viewer takes
it (it refuses while the recording has not arrived). Bound to 127.0.0.1, in daemon threads: it stops with
testbed.
"""
from __future__ import annotations

import http.server
import threading
import urllib.error
import urllib.request

from .timecursor import set_time_request

SCRIPT = """<script>
(function () {
  const request = new Uint8Array([%s]);
  function attempt() {
    const viewer = window._handle;
    if (!viewer) { setTimeout(attempt, 200); return; }
    viewer.viewer_control(request).then(
      function () { window.testbedSeeked = true; },
      function () { setTimeout(attempt, 300); });
  }
  attempt();
})();
</script>"""
HOP_HEADERS = {"connection", "keep-alive", "transfer-encoding", "content-length"}


def page_script(seconds: float) -> bytes:
    """The script that moves the page's viewer to ``seconds`` (paused)."""
    return (SCRIPT % ",".join(str(b) for b in set_time_request(seconds))).encode()


def serve_page(port: int, upstream_port: int, seconds: float) -> http.server.ThreadingHTTPServer:
    """Start serving 127.0.0.1:``port`` (in a daemon thread): rerun's web viewer from 127.0.0.1:``upstream_port``
    with the start-time script in its page."""
    script = page_script(seconds)

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 - http.server's name
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{upstream_port}{self.path}", timeout=60) as r:
                    status, headers, body = r.status, r.headers.items(), r.read()
            except urllib.error.HTTPError as err:
                status, headers, body = err.code, err.headers.items(), err.read()
            except OSError:
                self.send_error(502, "the rerun web viewer is not answering")
                return
            encoded = any(n.lower() == "content-encoding" and v != "identity" for n, v in headers)
            if self.path.split("?")[0] in ("/", "/index.html") and not encoded:
                body = body.replace(b"</body>", script + b"</body>", 1)
            self.send_response(status)
            for name, value in headers:
                if name.lower() not in HOP_HEADERS:
                    self.send_header(name, value)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args) -> None:  # no request log on the terminal
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), Handler)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, name="testbed-view-page", daemon=True).start()
    return server
