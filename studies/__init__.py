"""Case studies: each plant from its model to a comparison of controllers."""
