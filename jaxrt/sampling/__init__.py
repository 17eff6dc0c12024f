"""Random numbers and the warps that turn them into directions and points, with
their pdfs."""
