"""A local HTTP server that mimics an OpenAI-compatible endpoint (chat completions, embeddings), for the LLM
tests."""

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


class FakeServer:
    """A chat-completions server whose replies are scripted per request by ``respond(body) -> behaviour``.

    A behaviour is ``(status, text, delay_s)``: the assistant message ``text`` (status 200) or an error
    body, sent after ``delay_s`` seconds.
    """

    def __init__(self, respond):
        self.requests: list[dict] = []
        self.headers: list[dict] = []
        self.respond = respond
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):  # keep pytest output clean
                pass

            def do_POST(self):
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                server.requests.append({"path": self.path, "body": body})
                # header names are case-insensitive: canonical case whatever the client sent
                server.headers.append({k.title(): v for k, v in self.headers.items()})
                status, text, delay = server.respond(body, len(server.requests))
                if delay:
                    threading.Event().wait(delay)
                if status == 200 and self.path.endswith("/embeddings"):
                    payload = json.dumps(text).encode()
                elif status == 200:
                    payload = json.dumps(
                        {
                            "id": "x",
                            "object": "chat.completion",
                            "choices": [{"index": 0, "message": {"role": "assistant", "content": text}}],
                        }
                    ).encode()
                else:
                    payload = text.encode()
                try:
                    self.send_response(status)
                    self.send_header("Content-Type", "application/json")
                    if status == 429:
                        self.send_header("Retry-After", "0")
                    self.send_header("Content-Length", str(len(payload)))
                    self.end_headers()
                    self.wfile.write(payload)
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the client gave up (timeout test)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.thread = threading.Thread(target=self.httpd.serve_forever, args=(0.05,), daemon=True)
        self.thread.start()
        self.base_url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()
