"""Scene matching: alignment, NCC search, peak metrics, tracker, CNN, assistant map, decision rules
(pure); dataset and training; the perception node (shell)."""
