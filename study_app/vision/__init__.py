"""Remote vision screening material: colour-vision plates (generated) with the colour
arithmetic that checks them, and the contrast/acuity check (viewing geometry from a card,
optotypes, trial plan, scoring). A screening on an uncalibrated display, never a diagnosis."""
