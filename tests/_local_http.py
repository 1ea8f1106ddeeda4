"""A throwaway HTTP server on 127.0.0.1 for the Cloud Vision backend's tests (fake and faulty)."""

from __future__ import annotations

import threading
from http.server import ThreadingHTTPServer


class LocalVisionServer:
    """Serves `handler` on a free local port; `url` is its images:annotate endpoint."""

    def _serve(self, handler) -> None:
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/v1/images:annotate"
        self.thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
