"""What a request brings, checked before any work is done on it: body limits enforced while it streams in
(`limits`), images decoded with their headers checked (`images`), and depth whose values say other units
than it claims refused (`depth_units`)."""
