"""The radiosity solve: the prepared problem (sheets, C, transport R), receiver points and transport
rays with far clusters, patch emission and the sky policy, the first shot and progressive shooting."""
