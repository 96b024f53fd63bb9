"""Loop closing for the map backend: place recognition (`places`), geometric verification (`verification`),
pose-graph correction (`pose_graph`), run at keyframe insertions (`closing`)."""
