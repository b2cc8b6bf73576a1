"""OpenCV's methods measured beside ours on the same data in the same run: HOG descriptors (`hog`), LineMOD
on patches (`linemod`) and LineMOD as a whole-frame detector (`linemod_frames`)."""
