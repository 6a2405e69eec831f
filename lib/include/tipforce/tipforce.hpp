#pragma once
// The whole library from one include.
#include "tipforce/assert.hpp"
#include "tipforce/cantilever.hpp"
#include "tipforce/config.hpp"
#include "tipforce/drive.hpp"
#include "tipforce/force_model.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/inversion.hpp"
#include "tipforce/parameter_layout.hpp"
#include "tipforce/parameters.hpp"
#include "tipforce/reference.hpp"
#include "tipforce/window.hpp"
