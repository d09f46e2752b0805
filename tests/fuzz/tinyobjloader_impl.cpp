// tinyobjloader compiled into the fuzz build, so that it is instrumented like the code that calls it.
// Same configuration as the system library the main build links (tinyobjloader::tinyobjloader: float).
#define TINYOBJLOADER_IMPLEMENTATION
#include <tiny_obj_loader.h>
