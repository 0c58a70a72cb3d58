"""The rig in a browser (faces layer): a read-only live view served by the process that runs the rig
(``dyno run --web``, ``dyno ui --web``) and the run library (``dyno serve``).  docs/web.md.

The server never touches safety: it runs in its own thread on its own asyncio loop, fed through a
bounded queue by a poller listener that only copies values (:mod:`dyno.web.feed`); a slow or stuck
browser loses frames, never the poll loop's time.  Its one action, the optional STOP (``--web-stop``),
is handed to the rig's loop as the E-STOP key's abort (a software stop that can only make the rig safer).
"""
