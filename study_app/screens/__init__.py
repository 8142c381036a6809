"""The participant's screens: Markdown text, text flow, and drawing of each screen.

The modules ``markdown`` and ``textflow`` are pure (no display): text is parsed into blocks and
flowed into lines with a measuring function, so wrapping and paging are unit-tested with the
real font metrics but without a window.
"""
