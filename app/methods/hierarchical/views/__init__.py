"""What happens after a solve (issues 26, 28): radiance at any point of a solved run for views the
run was not refined for (`points`), and refinement rounds that weigh the links by the solved
radiance and solve again (`rounds`)."""
