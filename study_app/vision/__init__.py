"""Remote vision screening material: colour-vision plates (generated) and the colour
arithmetic that checks them. A screening on an uncalibrated display, never a diagnosis."""
