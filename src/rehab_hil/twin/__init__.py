"""The live twin: the plant model beside the rig during a session (issue 23).

``model.py`` binds the (augmented) plant model to the rig's samples and re-anchors it to the
measured states; ``monitor.py`` tests its residuals sequentially and raises ``model_mismatch``
events; ``interaction.py`` estimates the patient's interaction parameters online;
``diagnosis.py`` names the likeliest cause of a mismatch on the recent window; ``live.py`` runs
them off the loop's hot path.
"""
